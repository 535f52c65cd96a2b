"""Devices that lie, on loopback, and the `elphel` CLI run against them under a memory bound.

`FakeDevice` is a TCP server whose every connection is answered by a function of the
request (method, path, body) that writes whatever bytes it likes: an endless body, one
byte every second, a TIFF claiming 24000x24000 pixels. `run_elphel` runs the CLI in a
subprocess whose data segment is limited (RLIMIT_DATA: heap and anonymous mappings, what
a reader fills with a device's bytes; the address space also counts shared libraries and
reserved thread stacks, which is not memory a test can hold a reader to) and returns its
exit code, output and time.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

MEMORY_LIMIT_BYTES = 500 << 20
ROOT = Path(__file__).resolve().parents[3]

Responder = Callable[[str, str, bytes, socket.socket], None]


class FakeDevice:
    """A loopback TCP server answering each connection with ``respond`` in a thread.

    ``raw``: ``respond(conn)`` gets the connection as it is (a stage's line protocol)
    instead of a parsed HTTP request.
    """

    def __init__(self, respond: Callable[..., None], *, raw: bool = False) -> None:
        self.respond = respond
        self.raw = raw
        self.requests: list[tuple[str, str]] = []
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.closing = threading.Event()
        self.connections: list[socket.socket] = []
        threading.Thread(target=self._serve, daemon=True).start()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def _serve(self) -> None:
        while not self.closing.is_set():
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.connections.append(conn)
            threading.Thread(target=self._one, args=(conn,), daemon=True).start()

    def _one(self, conn: socket.socket) -> None:
        with conn:
            try:
                if self.raw:
                    self.respond(conn)
                    return
                method, path, body = _read_request(conn)
                self.requests.append((method, path))
                self.respond(method, path, body, conn)
            except OSError:
                pass  # the client gave up: what the test wants to see

    def close(self) -> None:
        self.closing.set()
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)  # wakes the accept() of _serve
        self.sock.close()
        for conn in self.connections:  # an endless answer ends at its next write
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)


def _read_request(conn: socket.socket) -> tuple[str, str, bytes]:
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = conn.recv(65536)
        if not chunk:
            raise OSError("closed before the request head")
        data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    method, path, _ = lines[0].split(" ", 2)
    length = 0
    for line in lines[1:]:
        name, _, value = line.partition(":")
        if name.strip().lower() == "content-length":
            length = int(value)
    while len(body) < length:
        body += conn.recv(65536)
    return method, path, body


def head(status: int = 200, *, content_type: str = "application/json", **headers: str) -> bytes:
    """A response head; ``chunked=...`` or ``content_length=...`` as keywords."""
    lines = [f"HTTP/1.1 {status} X", f"Content-Type: {content_type}", "Connection: close"]
    lines += [f"{k.replace('_', '-')}: {v}" for k, v in headers.items()]
    return ("\r\n".join(lines) + "\r\n\r\n").encode()


def whole(body: bytes, status: int = 200, *, content_type: str = "application/json") -> bytes:
    """A complete response with a Content-Length."""
    return head(status, content_type=content_type, content_length=str(len(body))) + body


def json_answer(value: object, status: int = 200) -> bytes:
    return whole(json.dumps(value).encode(), status)


def chunk(data: bytes) -> bytes:
    return f"{len(data):x}\r\n".encode() + data + b"\r\n"


def endless(conn: socket.socket, piece: bytes, *, content_type: str = "application/json") -> None:
    """A chunked body that never ends (until the client hangs up)."""
    conn.sendall(head(content_type=content_type, transfer_encoding="chunked"))
    block = chunk(piece * max(1, 65536 // len(piece)))
    while True:
        conn.sendall(block)


def drip(conn: socket.socket, *, every_s: float, content_type: str = "application/json") -> None:
    """A chunked body of one byte every ``every_s`` seconds, forever."""
    conn.sendall(head(content_type=content_type, transfer_encoding="chunked"))
    while True:
        conn.sendall(chunk(b" "))
        time.sleep(every_s)


@dataclass(frozen=True)
class Run:
    """A finished command: exit code, output, and its own time from after its imports."""

    code: int
    stdout: str
    stderr: str
    seconds: float


def run_elphel(
    args: list[str], *, timeout_s: float = 30.0, cwd: Path | None = None, **env: str
) -> Run:
    """``elphel ARGS`` in a subprocess limited to `MEMORY_LIMIT_BYTES` of data."""
    # The command's own time is measured in the child, after its imports: a loaded
    # machine may take seconds to start Python, which says nothing about the bounds.
    timing = Path(tempfile.mkdtemp()) / "seconds"
    code = (
        "import resource, sys, time\n"
        f"resource.setrlimit(resource.RLIMIT_DATA, ({MEMORY_LIMIT_BYTES}, {MEMORY_LIMIT_BYTES}))\n"
        "from elphel_host.cli import build_parser, main\n"
        "build_parser()\n"
        "start = time.monotonic()\n"
        "try:\n"
        "    code = main(sys.argv[1:])\n"
        "finally:\n"
        f"    open({str(timing)!r}, 'w').write(str(time.monotonic() - start))\n"
        "sys.exit(code)\n"
    )
    paths = [ROOT / "host/src", ROOT / "target/camera/src", ROOT / "simulator/src"]
    environ = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(map(str, paths)),
        "OPENBLAS_NUM_THREADS": "1",
        "OMP_NUM_THREADS": "1",
        "ELPHEL_CAMERA_TOKEN": "t",
        **env,
    }
    done = subprocess.run(
        [sys.executable, "-c", code, *args],
        capture_output=True,
        text=True,
        env=environ,
        timeout=timeout_s,
        cwd=cwd,
        check=False,
    )
    seconds = float(timing.read_text()) if timing.exists() else float("nan")
    shutil.rmtree(timing.parent, ignore_errors=True)
    return Run(done.returncode, done.stdout, done.stderr, seconds)


def assert_one_line_failure(run: Run, *needles: str) -> None:
    """Exit 1, one terminal-safe error line last on stderr holding each of ``needles``.

    Lines before it are the command's progress (long commands report it on stderr).
    """
    lines = run.stderr.splitlines()
    assert run.code == 1, (run.code, run.stderr[-2000:])
    errors = [line for line in lines if line.startswith("elphel: ")]
    assert len(errors) == 1 and lines[-1] == errors[0], run.stderr[-2000:]
    assert "Traceback" not in run.stderr
    assert "\x1b" not in run.stderr and "\x07" not in run.stderr
    assert len(errors[0]) <= 600, len(errors[0])
    for needle in needles:
        assert needle in errors[0], (needle, errors[0])
