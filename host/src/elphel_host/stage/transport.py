"""Open a stage link from a pyserial URL and exchange lines over it."""

from __future__ import annotations

import contextlib
import logging
import socket
import struct
import time

import serial
from serial.urlhandler.protocol_socket import Serial as _PySerialSocket

from elphel_host.errors import StageConnectionError, StageProtocolError

log = logging.getLogger(__name__)

BAUD = 115200


def _bytes_ready(sock: socket.socket) -> int:
    """Bytes a socket holds (FIONREAD); 0 where the system can't tell (Windows)."""
    try:
        import fcntl
        import termios
    except ImportError:  # pragma: no cover - not POSIX: reads go byte by byte
        return 0
    raw = fcntl.ioctl(sock.fileno(), termios.FIONREAD, b"\0\0\0\0")
    return int(struct.unpack("i", raw)[0])


class _SocketPort(_PySerialSocket):
    """pyserial's ``socket://`` port, reading what has arrived and closing without a pause.

    pyserial sleeps 0.3 s in ``close()`` "in case of quick reconnects"; the stage client
    paces its own reconnects (retries with deadlines), so the pause only made every
    reconnect after a dropped link slower.
    """

    _socket: socket.socket | None
    is_open: bool

    @property
    def in_waiting(self) -> int:
        """Bytes ready to read (pyserial's answer is only 0 or 1).

        With 0 or 1, a reply line is read one byte per call, a few system calls per byte;
        on a busy machine each of them may wait for the CPU (and for the GIL, next to a
        simulator thread), which made a 100-byte reply take milliseconds.
        """
        n = int(super().in_waiting)
        if n and self._socket is not None:
            n = max(n, _bytes_ready(self._socket))
        return n

    def close(self) -> None:
        if not self.is_open:
            return
        sock, self._socket = self._socket, None
        if sock is not None:
            with contextlib.suppress(OSError):  # the peer may have reset the link already
                sock.shutdown(socket.SHUT_RDWR)
            sock.close()
        self.is_open = False


def open_link(url: str, *, timeout_s: float = 0.05) -> serial.SerialBase:
    """Open `url` (device path, ``socket://host:port``, pty path, any pyserial URL).

    DTR/RTS are set low before opening so NodeMCU-style boards are not reset by it.
    """
    try:
        if url.lower().startswith("socket://"):
            port = _SocketPort(None, baudrate=BAUD, timeout=timeout_s)
            port.port = url
        else:
            port = serial.serial_for_url(url, baudrate=BAUD, timeout=timeout_s, do_not_open=True)
        port.dtr = False
        port.rts = False
        port.open()
    except (serial.SerialException, OSError, ValueError) as e:
        raise StageConnectionError(f"cannot open stage link {url!r}: {e}") from e
    return port


class LineLink:
    """Line I/O on an open port: write a line, read lines until a deadline.

    A line longer than ``line_limit_bytes`` (the protocol's are under 200) is a
    `StageProtocolError`: a board sending bytes without end cannot fill the memory.
    """

    def __init__(self, port: serial.SerialBase, url: str, *, line_limit_bytes: int = 4096) -> None:
        self.port = port
        self.url = url
        self.line_limit_bytes = line_limit_bytes
        self._buf = bytearray()

    def write_line(self, line: str) -> None:
        self._write(line.encode("ascii") + b"\n")

    def write_raw(self, data: bytes) -> None:
        self._write(data)

    def _write(self, data: bytes) -> None:
        log.debug("stage <- %r", data)
        try:
            self.port.write(data)
            self.port.flush()
        except (serial.SerialException, OSError) as e:
            raise StageConnectionError(f"stage link {self.url!r} lost while writing: {e}") from e

    def read_line(self, deadline: float) -> str | None:
        """Next line (without newline) or None when the monotonic deadline passes."""
        while True:
            nl = self._buf.find(b"\n")
            if nl >= 0:
                raw = bytes(self._buf[:nl])
                del self._buf[: nl + 1]
                log.debug("stage -> %r", raw)
                return raw.rstrip(b"\r").decode("ascii", errors="replace")
            if time.monotonic() >= deadline:
                return None
            try:
                chunk = self.port.read(max(1, self.port.in_waiting))
            except (serial.SerialException, OSError) as e:
                raise StageConnectionError(
                    f"stage link {self.url!r} lost while reading: {e}"
                ) from e
            if chunk:
                self._buf.extend(chunk)
                if len(self._buf) > self.line_limit_bytes and b"\n" not in self._buf:
                    self._buf.clear()
                    raise StageProtocolError(
                        f"stage {self.url!r}: a line longer than {self.line_limit_bytes} bytes "
                        "(limit stage_line_bytes; raise ELPHEL_LIMIT_STAGE_LINE_BYTES)"
                    )

    def drain(self, quiet_s: float = 0.0) -> list[str]:
        """Discard pending input; return the complete lines that were in it."""
        lines = []
        deadline = time.monotonic() + quiet_s
        while True:
            line = self.read_line(deadline)
            if line is None:
                break
            lines.append(line)
        self._buf.clear()
        return lines

    def close(self) -> None:
        # pyserial's socket:// close() skips socket.close() when shutdown() fails on a
        # connection the peer already reset; close the socket ourselves.
        sock = getattr(self.port, "_socket", None)
        try:
            self.port.close()
        except (serial.SerialException, OSError) as e:  # closing a dead link is not an error
            log.debug("closing %s: %s", self.url, e)
        if sock is not None:
            sock.close()
