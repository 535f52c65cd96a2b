"""The ESP8266's links as the firmware sees them: its UART, its sockets, select.poll().

The UART reads and writes the board's receive buffer and output sink; a socket is a real
loopback socket (so the host's client connects over real TCP); a poll object waits on
both against the board's virtual clock.
"""

from __future__ import annotations

import contextlib
import errno
import os
import socket as _socket
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from elphel_sim.micropython.esp8266 import SimEsp8266

# Virtual cost of one pin or UART access (the real chip spends a few us in Python).
PIN_ACCESS_US = 2
# Virtual cost of one select.poll() call with its main-loop iteration: MicroPython on the
# 80 MHz ESP8266 spends tens of us there. Charging only a pin access let the firmware's
# poll(0) loop before a due step spin ~60 times per step, so a move ran at about real
# time, not time_scale times faster, and slower still on a loaded machine.
POLL_US = 50
UART_RX_BUFFER = 256

Garbler = Callable[[bytes], bytes]


class FakeUART:
    def __init__(self, board: SimEsp8266) -> None:
        self.board = board

    def read(self, n: int = -1) -> bytes | None:
        self.board.clock.advance(PIN_ACCESS_US)
        return self.board.uart_take(n)

    def any(self) -> int:
        return len(self.board.uart_rx)

    def write(self, data: bytes | str) -> int:
        if isinstance(data, str):
            data = data.encode()
        self.board.clock.advance(PIN_ACCESS_US)
        self.board.uart_emit(bytes(data))
        return len(data)


class FakeSocket:
    """A firmware socket backed by a real loopback socket."""

    def __init__(
        self, board: SimEsp8266, real: _socket.socket | None, *, listener: bool = False
    ) -> None:
        self.board = board
        self.real = real
        self.listener = listener
        self.closed = False

    def setsockopt(self, *args: Any) -> None:
        pass

    def bind(self, addr: tuple[str, int]) -> None:
        self.listener = True
        self.real = self.board.tcp_listener(addr[1])

    def listen(self, backlog: int = 1) -> None:
        pass

    def setblocking(self, flag: bool) -> None:
        if self.real is not None and not self.listener:
            self.real.setblocking(flag)

    def accept(self) -> tuple[FakeSocket, tuple[str, int]]:
        assert self.real is not None
        try:
            conn, addr = self.real.accept()
        except BlockingIOError as e:
            raise OSError(errno.EAGAIN, "EAGAIN") from e
        conn.setblocking(False)
        fake = FakeSocket(self.board, conn)
        self.board.clients.append(fake)
        if self.board.link_down:
            # The firmware sees end-of-stream at once and closes it, as after a drop.
            with contextlib.suppress(OSError):
                conn.shutdown(_socket.SHUT_RDWR)
        return fake, addr

    def recv(self, n: int) -> bytes:
        if self.real is None or self.closed:
            raise OSError(errno.ENOTCONN, "ENOTCONN")
        data = self.real.recv(n)
        return self.board.garble_in(data) if data else data

    def send(self, data: bytes) -> int:
        if self.real is None or self.closed:
            raise OSError(errno.ENOTCONN, "ENOTCONN")
        return self.real.send(self.board.garble_out(bytes(data)))

    def write(self, data: bytes) -> int:
        return self.send(data)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        if self.listener:
            return  # the board keeps its real listening socket across resets
        if self.real is not None:
            self.real.close()
        if self in self.board.clients:
            self.board.clients.remove(self)

    def fileno(self) -> int:
        return -1 if self.real is None or self.closed else self.real.fileno()


class FakePoll:
    def __init__(self, board: SimEsp8266) -> None:
        self.board = board
        self.objs: dict[int, Any] = {}

    def register(self, obj: Any, mask: int = 1) -> None:
        self.objs[id(obj)] = obj

    def unregister(self, obj: Any) -> None:
        self.objs.pop(id(obj), None)

    def _ready(self) -> list[tuple[Any, int]]:
        out: list[tuple[Any, int]] = []
        fds: dict[int, Any] = {}
        for obj in self.objs.values():
            if isinstance(obj, FakeUART):
                if self.board.uart_rx:
                    out.append((obj, 1))
            elif isinstance(obj, FakeSocket) and obj.fileno() >= 0:
                fds[obj.fileno()] = obj
        if fds:
            import select as _select

            ready, _, _ = _select.select(list(fds), [], [], 0)
            out.extend((fds[fd], 1) for fd in ready)
        return out

    def poll(self, timeout_ms: int = -1) -> list[tuple[Any, int]]:
        board = self.board
        board.clock.advance(POLL_US)
        ready = self._ready()
        if ready or timeout_ms == 0:
            return ready
        fds = [
            o.fileno() for o in self.objs.values() if isinstance(o, FakeSocket) and o.fileno() >= 0
        ]
        fds.append(board.wake_r)
        wait_us = 1_000_000 if timeout_ms < 0 else timeout_ms * 1000
        got = board.clock.wait_io(wait_us, fds)
        if board.wake_r in got:
            with contextlib.suppress(BlockingIOError):
                os.read(board.wake_r, 4096)
        return self._ready()
