"""Open a stage link from a pyserial URL and exchange lines over it."""

from __future__ import annotations

import logging
import time

import serial

from elphel_host.errors import StageConnectionError

log = logging.getLogger(__name__)

BAUD = 115200


def open_link(url: str, *, timeout_s: float = 0.05) -> serial.SerialBase:
    """Open `url` (device path, ``socket://host:port``, pty path, any pyserial URL).

    DTR/RTS are set low before opening so NodeMCU-style boards are not reset by it.
    """
    try:
        port = serial.serial_for_url(url, baudrate=BAUD, timeout=timeout_s, do_not_open=True)
        port.dtr = False
        port.rts = False
        port.open()
    except (serial.SerialException, OSError, ValueError) as e:
        raise StageConnectionError(f"cannot open stage link {url!r}: {e}") from e
    return port


class LineLink:
    """Line I/O on an open port: write a line, read lines until a deadline."""

    def __init__(self, port: serial.SerialBase, url: str) -> None:
        self.port = port
        self.url = url
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
