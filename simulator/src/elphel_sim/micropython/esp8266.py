"""A simulated ESP8266 that runs the stage firmware files unchanged.

The firmware's ``import machine``/``time``/``network``/``socket``/``select``/``os`` resolve
to fakes bound to this board (its virtual clock, pins, UART and TCP port); ``open``
reads the board's own file system directory. Each board has its own module namespace,
so several can run in one process.

This module holds the board's wiring (clock, pins, UART buffer, TCP listener, reset and
watchdog, the firmware thread); `links` holds the UART, socket and poll objects and
`modules` the fake modules and the import system the firmware runs with.
"""

from __future__ import annotations

import contextlib
import os
import random
import socket as _socket
import threading
from collections.abc import Callable
from pathlib import Path

from elphel_sim.micropython.clock import SimReset, SimShutdown, VirtualClock
from elphel_sim.micropython.links import UART_RX_BUFFER, FakeSocket, Garbler
from elphel_sim.micropython.modules import HARD_RESET, PWRON_RESET, WDT_RESET, FirmwareModules
from elphel_sim.micropython.pins import PinBank

WDT_DEADLINE_US = 3_200_000  # SDK soft watchdog: 2 ticks of 1.6 s after the last feed


def default_firmware_dir() -> Path:
    env = os.environ.get("ELPHEL_STAGE_FIRMWARE")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[4] / "target" / "esp8266"


class SimEsp8266:
    """The board: clock, pins, UART, TCP, file system, watchdog; runs the firmware."""

    def __init__(
        self,
        *,
        fs_dir: Path,
        firmware_dir: Path | None = None,
        time_scale: float = 1.0,
        tcp_port: int = 0,
        seed: int = 0,
        unique_id: bytes = b"\x5e\x1a\x9e\x00\x00\x01",
    ) -> None:
        self.fs_dir = Path(fs_dir)
        self.firmware_dir = firmware_dir or default_firmware_dir()
        self.clock = VirtualClock(time_scale)
        self.pins = PinBank()
        self.rng = random.Random(seed)
        self.unique_id = unique_id
        self.uart_rx = bytearray()
        self.uart_lock = threading.Lock()
        self.uart_sink: Callable[[bytes], None] = lambda data: None
        self.wake_r, self.wake_w = os.pipe()
        os.set_blocking(self.wake_r, False)
        os.set_blocking(self.wake_w, False)
        self.requested_tcp_port = tcp_port
        self.listener: _socket.socket | None = None
        self.clients: list[FakeSocket] = []
        # While True the WiFi link is down: connections are cut as soon as they come.
        self.link_down = False
        self.garble_in: Garbler = lambda data: data
        self.garble_out: Garbler = lambda data: data
        self.reset_cause = PWRON_RESET
        self.resets = 0
        self._reset_request: int | None = None
        self._shutdown = False
        self._wdt_last: int | None = None
        self.clock.checks.append(self._check)
        self.thread: threading.Thread | None = None
        self.crash: BaseException | None = None
        self.booted = threading.Event()

    # ---- links ----------------------------------------------------------------------
    def tcp_listener(self, port: int) -> _socket.socket:
        if self.listener is None:
            s = _socket.socket(_socket.AF_INET, _socket.SOCK_STREAM)
            s.setsockopt(_socket.SOL_SOCKET, _socket.SO_REUSEADDR, 1)
            try:
                s.bind(("127.0.0.1", self.requested_tcp_port))
            except OSError as e:
                s.close()
                where = f"127.0.0.1:{self.requested_tcp_port}"
                raise OSError(e.errno, f"stage: cannot listen on {where}: {e.strerror}") from e
            s.listen(4)
            s.setblocking(False)
            self.listener = s
        return self.listener

    def bind_tcp_now(self) -> int:
        """Open the loopback listener before boot so its port is known at once."""
        return int(self.tcp_listener(0).getsockname()[1])

    def uart_feed(self, data: bytes) -> None:
        """Bytes arriving at the board's RX pin (from the pty)."""
        data = self.garble_in(data)
        with self.uart_lock:
            room = UART_RX_BUFFER - len(self.uart_rx)
            self.uart_rx.extend(data[: max(0, room)])
        with contextlib.suppress(BlockingIOError):
            os.write(self.wake_w, b"u")

    def uart_take(self, n: int) -> bytes | None:
        with self.uart_lock:
            if not self.uart_rx:
                return None
            k = len(self.uart_rx) if n is None or n < 0 else min(n, len(self.uart_rx))
            data = bytes(self.uart_rx[:k])
            del self.uart_rx[:k]
            return data

    def uart_emit(self, data: bytes) -> None:
        self.uart_sink(self.garble_out(data))

    def drop_clients(self) -> None:
        """Cut every TCP connection, as a WiFi drop does; callable from any thread.

        Only shuts the real sockets down: the firmware then sees end-of-stream and closes
        them itself. Closing them here, from another thread, would pull the descriptor out
        from under the firmware's select() (EBADF kills the board) or let the number be
        reused by a new connection while the firmware still polls it.
        """
        for c in list(self.clients):
            if c.real is not None and not c.closed:
                with contextlib.suppress(OSError):
                    c.real.shutdown(_socket.SHUT_RDWR)

    def _close_clients(self) -> None:
        """Close every TCP connection; only on the firmware thread or after it ended."""
        self.drop_clients()
        for c in list(self.clients):
            c.close()

    # ---- reset, watchdog ---------------------------------------------------------
    def request_reset(self, cause: int = HARD_RESET) -> None:
        self._reset_request = cause

    def _check(self) -> None:
        if self._shutdown:
            raise SimShutdown
        if self._reset_request is not None:
            cause, self._reset_request = self._reset_request, None
            raise SimReset(cause)
        if self._wdt_last is not None and self.clock.now_us - self._wdt_last > WDT_DEADLINE_US:
            self._wdt_last = None
            raise SimReset(WDT_RESET)

    def wdt_feed(self) -> None:
        self._wdt_last = self.clock.now_us

    # ---- firmware -------------------------------------------------------------------
    def start(self) -> None:
        self.thread = threading.Thread(target=self._run, name="sim-esp8266", daemon=True)
        self.thread.start()

    def close(self) -> None:
        self._shutdown = True
        with contextlib.suppress(OSError):
            os.write(self.wake_w, b"x")
        if self.thread is not None:
            self.thread.join(timeout=10)
        self._close_clients()
        if self.listener is not None:
            self.listener.close()
            self.listener = None
        for fd in (self.wake_r, self.wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)

    def _run(self) -> None:
        while not self._shutdown:
            try:
                self._boot()
                return  # main.py returned: the board sits in the REPL
            except SimReset as e:
                self.resets += 1
                self.reset_cause = int(e.args[0]) if e.args else HARD_RESET
                self._wdt_last = None
                self._close_clients()
                continue
            except SimShutdown:
                return
            except BaseException as e:  # a firmware crash ends in the REPL on a real board
                self.crash = e
                self.uart_emit(f"Traceback: {type(e).__name__}: {e}\r\n".encode())
                return

    def _boot(self) -> None:
        modules = FirmwareModules(self)
        for name in ("boot.py", "main.py"):
            path = self.firmware_dir / name
            if path.exists():
                modules.exec_file(path, "__main__")
                self.booted.set()
