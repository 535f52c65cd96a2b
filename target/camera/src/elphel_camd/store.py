"""What the daemon keeps on disk: the bearer token file and each port's accepted parameters.

Files the daemon writes are never left torn: the token file and parameter snapshots are
written to a temporary file in the same directory, flushed to disk, then renamed over the
old one (`write_atomic`, the one atomic-write helper of the daemon); parameter changes are
appended to a per-port journal whose lines carry a CRC, so a crash or ``kill -9`` at any
moment leaves the last acknowledged state readable (`ParamStore`).
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import secrets
import tempfile
import threading
import zlib
from collections.abc import Mapping
from pathlib import Path

from elphel_camd.errors import ConfigError, StateWriteError

log = logging.getLogger(__name__)

PARAMS_VERSION = 1

# -- atomic files ----------------------------------------------------------------------------


def write_atomic(path: Path, data: bytes, *, mode: int = 0o644, sync: bool = True) -> None:
    """Replace ``path`` with ``data`` so that readers see the old or the new file only.

    The rename alone makes the replacement atomic for a killed process; ``sync`` also
    flushes data and directory to the disk first, for a power loss.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, mode)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            if sync:
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    if sync:
        fsync_path(path.parent)


def _journal_line(text: bytes) -> bytes:
    """A journal line: the state's JSON, a tab and its CRC-32 in hex."""
    return text + b"\t%08x\n" % zlib.crc32(text)


def fsync_path(path: Path) -> None:
    """Flush a file's or a directory's data and metadata to the disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def last_journal_line(path: Path) -> bytes | None:
    """The last intact line of a `ParamStore` journal (without its CRC), or None."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return None
    for line in reversed(data.split(b"\n")):
        text, _, crc = line.rpartition(b"\t")
        if text and crc == b"%08x" % zlib.crc32(text):
            return text
        if line:
            log.warning("skipping a torn line at the end of %s", path)
    return None


def remove_stale_temporaries(directory: Path) -> None:
    """Delete temporary files a killed writer left behind."""
    if directory.is_dir():
        for stale in directory.glob(".*.tmp"):
            with contextlib.suppress(OSError):
                stale.unlink()


def new_token() -> str:
    """A random bearer token (192 bits, URL-safe) that never starts with ``-``.

    One URL-safe token in 64 would start with a dash, and ``--token -abc...`` on a command
    line is then taken for an option.
    """
    token = secrets.token_urlsafe(24)
    while token.startswith("-"):
        token = secrets.token_urlsafe(24)
    return token


def load_or_create_token(path: Path) -> str:
    """The token in ``path``; on first start a new random one, written there with mode 0600."""
    try:
        token = path.read_text().strip()
    except FileNotFoundError:
        token = ""
    except OSError as e:
        raise ConfigError(f"cannot read token file {path}: {e}") from e
    if token:
        if path.stat().st_mode & 0o077:
            log.warning("token file %s is readable by others; chmod 600 it", path)
        return token
    token = new_token()
    try:
        write_atomic(path, (token + "\n").encode(), mode=0o600)
    except OSError as e:
        raise ConfigError(f"cannot create token file {path}: {e}") from e
    log.info("new bearer token written to %s", path)
    return token


# -- per-port parameters ----------------------------------------------------------------------


class ParamStore:
    """Accepted parameters of each port: a snapshot file plus an append-only journal.

    A save appends one line, the port's whole state, to ``port<N>.log`` with a single
    ``write`` call and returns: from then on a killed daemon restarts with it (the kernel
    holds the line even if the process dies), and it costs microseconds where replacing a
    file costs a rename in the file system's journal. Loading takes the last intact line
    (each carries a CRC-32, so a line torn by a power loss is skipped), or the snapshot
    ``port<N>.json`` when the journal is empty. A background thread flushes the journals to
    the disk within `flush_interval_s` (``sync_each=True`` flushes before `save`
    returns) and, once a journal passes `compact_bytes`, writes its last state as the new
    snapshot (atomically) and replaces the journal by one holding only the newest line
    (also atomically), so the journal stays near `compact_bytes` under steady writes too:
    a save that finds it past twice that compacts before it returns.
    A save that cannot be written (disk full, read-only directory) raises
    `StateWriteError` and leaves the files as they were. A ``with`` block closes the store.

    Parameters
    ----------
    directory
        Where ``port<N>.json`` and ``port<N>.log`` live.
    sync_each
        Flush every line to the disk before `save` returns (for a power loss).
    """

    flush_interval_s = 0.25
    compact_bytes = 64 * 1024

    def __init__(self, directory: Path, *, sync_each: bool = False) -> None:
        self.directory = directory
        self.sync_each = sync_each
        directory.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(directory)
        self._journals: dict[int, int] = {}  # port -> file descriptor (O_APPEND)
        self._last: dict[int, bytes] = {}  # port -> the last line saved
        self._locks: dict[int, threading.Lock] = {}
        self._dirty: set[int] = set()
        self._wake = threading.Condition()
        self._closed = False
        self._flusher: threading.Thread | None = None
        if not sync_each:
            self._flusher = threading.Thread(target=self._flush_loop, name="params-fsync")
            self._flusher.daemon = True
            self._flusher.start()

    def path(self, port: int) -> Path:
        """The snapshot file of a port."""
        return self.directory / f"port{port}.json"

    def journal_path(self, port: int) -> Path:
        return self.directory / f"port{port}.log"

    def _journal(self, port: int) -> int:
        fd = self._journals.get(port)
        if fd is None:
            flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_CLOEXEC", 0)
            fd = self._journals[port] = os.open(self.journal_path(port), flags, 0o644)
            fsync_path(self.directory)  # the new journal's directory entry, once
        return fd

    def save(self, port: int, sensor: str, params: Mapping[str, int]) -> None:
        body = {"version": PARAMS_VERSION, "port": port, "sensor": sensor, "params": dict(params)}
        text = json.dumps(body, sort_keys=True, separators=(",", ":")).encode()
        line = _journal_line(text)
        lock = self._locks.get(port) or self._locks.setdefault(port, threading.Lock())
        with lock:
            try:
                fd = self._journal(port)
                size = os.fstat(fd).st_size
                written = os.write(fd, line)
                if written != len(line):
                    os.ftruncate(fd, size)  # no torn line left behind
                    raise OSError(errno.ENOSPC, f"short write ({written} of {len(line)} bytes)")
                if self.sync_each:
                    os.fsync(fd)
            except OSError as e:
                raise StateWriteError(
                    f"port {port}: cannot save parameters to {self.journal_path(port)}: "
                    f"{e.strerror or e}; the change was refused, the last saved settings stay"
                ) from e
            self._last[port] = text
        if self.sync_each:
            if size + len(line) > self.compact_bytes:
                self._compact(port)
        elif size + len(line) > 2 * self.compact_bytes:
            # Writes faster than the flusher compacts: this one compacts (milliseconds,
            # once per compact_bytes), so the journal never grows past twice its bound.
            self._compact(port)
        else:
            with self._wake:
                self._dirty.add(port)
                self._wake.notify()

    def _compact(self, port: int) -> None:
        """Write the last state as the snapshot, then restart the journal from the newest line.

        The snapshot and the new journal are written and flushed (milliseconds) without the
        port's lock, so saves go on meanwhile. Under the lock the new journal gets the
        saves that came in between and is renamed over the old one: microseconds, so steady
        writes cannot postpone the compaction and a save never waits for the disk. A kill at
        any step leaves either the old journal or the new one, each ending with the newest
        acknowledged state.
        """
        lock = self._locks[port]
        with lock:
            text = self._last[port]
        write_atomic(self.path(port), text, sync=True)
        path = self.journal_path(port)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        try:
            os.fchmod(fd, 0o644)
            os.write(fd, _journal_line(text))
            os.fsync(fd)
            with lock:
                newest = self._last[port]
                if newest != text:
                    os.write(fd, _journal_line(newest))
                    if self.sync_each:
                        os.fsync(fd)
                os.replace(tmp, path)
                flags = os.O_WRONLY | os.O_APPEND | getattr(os, "O_CLOEXEC", 0)
                old, self._journals[port] = self._journals[port], os.open(path, flags)
            os.close(old)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
        finally:
            os.close(fd)
        fsync_path(path.parent)

    def _flush(self, ports: set[int]) -> None:
        # Without the port's lock: an fsync takes milliseconds, a save must not wait for it.
        for port in ports:
            fd = self._journals[port]
            try:
                os.fsync(fd)
                if os.fstat(fd).st_size > self.compact_bytes:
                    self._compact(port)
            except OSError as e:  # the next save or flush tries again
                log.error("port %d: cannot flush saved parameters: %s", port, e)

    def _flush_loop(self) -> None:
        while True:
            with self._wake:
                while not self._dirty and not self._closed:
                    self._wake.wait()
                dirty, self._dirty = self._dirty, set()
                closed = self._closed
            self._flush(dirty)
            if closed:
                return
            # Coalesce: a burst of changes costs one flush per interval, not one per change
            # (each flush stalls other writes to the file system for milliseconds).
            with self._wake:
                self._wake.wait_for(lambda: self._closed, timeout=self.flush_interval_s)

    def __enter__(self) -> ParamStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Flush what is pending, stop the background thread and close the journals."""
        with self._wake:
            self._closed = True
            self._wake.notify()
        if self._flusher is not None:
            self._flusher.join(timeout=10)
        for port, fd in list(self._journals.items()):
            with self._locks[port]:
                os.close(fd)
                del self._journals[port]

    def load(self, port: int, sensor: str) -> dict[str, int] | None:
        """Saved parameters of a port, or None (no file, other sensor, unreadable file)."""
        path = self.journal_path(port)
        try:
            text = last_journal_line(path)
            if text is None:
                path = self.path(port)
                text = path.read_bytes()
            body = json.loads(text)
        except FileNotFoundError:
            return None
        except (OSError, json.JSONDecodeError) as e:
            log.error("port %d: ignoring unreadable saved parameters %s: %s", port, path, e)
            return None
        ok = (
            isinstance(body, dict)
            and body.get("version") == PARAMS_VERSION
            and isinstance(body.get("params"), dict)
            and all(isinstance(v, int) for v in body["params"].values())
        )
        if not ok:
            log.error("port %d: ignoring saved parameters %s of unknown form", port, path)
            return None
        if body.get("sensor") != sensor:
            log.warning(
                "port %d: saved parameters are for %s, the port has %s; not restored",
                port,
                body.get("sensor"),
                sensor,
            )
            return None
        return dict(body["params"])
