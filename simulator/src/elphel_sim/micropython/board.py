"""A simulated ESP8266 that runs the stage firmware files unchanged.

The firmware's ``import machine``/``time``/``network``/``socket``/``select``/``os`` resolve
to fakes bound to this board (its virtual clock, pins, UART and TCP port); ``open``
reads the board's own file system directory. Each board has its own module namespace,
so several can run in one process.
"""

from __future__ import annotations

import builtins
import contextlib
import errno
import os
import random
import socket as _socket
import threading
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any

from elphel_sim.micropython.clock import SimReset, SimShutdown, VirtualClock
from elphel_sim.micropython.pins import PinBank

# Virtual cost of one pin or UART access (the real chip spends a few us in Python).
PIN_ACCESS_US = 2
# Virtual cost of one select.poll() call with its main-loop iteration: MicroPython on the
# 80 MHz ESP8266 spends tens of us there. Charging only a pin access let the firmware's
# poll(0) loop before a due step spin ~60 times per step, so a move ran at about real
# time, not time_scale times faster, and slower still on a loaded machine.
POLL_US = 50
WDT_DEADLINE_US = 3_200_000  # SDK soft watchdog: 2 ticks of 1.6 s after the last feed
UART_RX_BUFFER = 256

PWRON_RESET, HARD_RESET, WDT_RESET, DEEPSLEEP_RESET, SOFT_RESET = 0, 6, 1, 5, 4

Garbler = Callable[[bytes], bytes]


def default_firmware_dir() -> Path:
    env = os.environ.get("ELPHEL_STAGE_FIRMWARE")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[4] / "target" / "esp8266"


class FakeUART:
    def __init__(self, board: SimBoard) -> None:
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
        self, board: SimBoard, real: _socket.socket | None, *, listener: bool = False
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
    def __init__(self, board: SimBoard) -> None:
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


class SimBoard:
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
            s.bind(("127.0.0.1", self.requested_tcp_port))
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


class FirmwareModules:
    """The firmware's import system for one boot: fakes plus the board's .py files."""

    def __init__(self, board: SimBoard) -> None:
        self.board = board
        self.loaded: dict[str, types.ModuleType] = {}
        self.fakes = build_fakes(board)
        self.builtins = dict(vars(builtins))
        self.builtins["__import__"] = self._import
        self.builtins["open"] = self._open

    def _open(self, path: str, mode: str = "r", *args: Any, **kw: Any) -> Any:
        if os.path.isabs(path) or ".." in Path(path).parts:
            raise OSError(errno.ENOENT, path)
        return open(self.board.fs_dir / path, mode, *args, **kw)

    def _import(
        self, name: str, globals: Any = None, locals: Any = None, fromlist: Any = (), level: int = 0
    ) -> types.ModuleType:
        base = name.split(".")[0]
        if base.startswith("u") and base[1:] in self.fakes:
            base = base[1:]
        if base in self.fakes:
            return self.fakes[base]
        if base in self.loaded:
            return self.loaded[base]
        for root in (self.board.fs_dir, self.board.firmware_dir):
            path = root / f"{base}.py"
            if path.exists():
                return self.exec_file(path, base)
        if base in ("json", "gc", "struct", "collections", "math", "re", "errno", "binascii"):
            return __import__(name, globals, locals, fromlist, level)
        raise ImportError(f"no module named '{name}' on the simulated board")

    def exec_file(self, path: Path, name: str) -> types.ModuleType:
        mod = types.ModuleType(name)
        mod.__dict__["__builtins__"] = self.builtins
        mod.__dict__["__file__"] = path.name
        if name != "__main__":
            self.loaded[name] = mod
        code = compile(path.read_text(), str(path), "exec")
        exec(code, mod.__dict__)
        return mod


def _ticks_diff(a: int, b: int) -> int:
    half = 1 << 29
    return ((a - b + half) & ((1 << 30) - 1)) - half


def build_fakes(board: SimBoard) -> dict[str, types.ModuleType]:
    clock = board.clock
    pins = board.pins
    mask = (1 << 30) - 1

    t = types.ModuleType("time")
    t.ticks_us = lambda: clock.now_us & mask  # type: ignore[attr-defined]
    t.ticks_ms = lambda: (clock.now_us // 1000) & mask  # type: ignore[attr-defined]
    t.ticks_cpu = t.ticks_us  # type: ignore[attr-defined]
    t.ticks_diff = _ticks_diff  # type: ignore[attr-defined]
    t.ticks_add = lambda a, d: (a + d) & mask  # type: ignore[attr-defined]
    t.sleep_us = lambda us: clock.advance(max(0, int(us)))  # type: ignore[attr-defined]
    t.sleep_ms = lambda ms: clock.advance(max(0, int(ms)) * 1000)  # type: ignore[attr-defined]
    t.sleep = lambda s: clock.advance(int(s * 1_000_000))  # type: ignore[attr-defined]
    t.time = lambda: 946684800 // 1 + clock.now_us // 1_000_000  # type: ignore[attr-defined]

    m = types.ModuleType("machine")

    class Pin:
        IN, OUT, OPEN_DRAIN = 0, 1, 2
        PULL_UP = 1
        IRQ_RISING, IRQ_FALLING = 1, 2

        def __init__(
            self, num: int, mode: int = -1, pull: Any = None, *, value: int | None = None
        ) -> None:
            pins.check(num)
            self.num = num
            self.mode = mode
            if value is not None:
                self.value(value)

        def value(self, v: int | None = None) -> int | None:
            clock.advance(PIN_ACCESS_US)
            if v is None:
                return pins.read(self.num, clock.now_us, self.mode == Pin.OUT)
            pins.write(self.num, v, clock.now_us)
            return None

        def __call__(self, v: int | None = None) -> int | None:
            return self.value(v)

        def on(self) -> None:
            self.value(1)

        def off(self) -> None:
            self.value(0)

        def irq(self, *args: Any, hard: bool = False, **kw: Any) -> None:
            if hard:
                raise ValueError("hard IRQ not supported")

    def time_pulse_us(pin: Pin, level: int, timeout_us: int = 1_000_000) -> int:
        sig = pins.inputs.get(pin.num)
        clock.advance(PIN_ACCESS_US)

        def value_now() -> int:
            return 1 if sig is None else sig.level_at(clock.now_us)

        def run_until_change(limit_us: int) -> bool:
            """Advance to the next change of the pin (True) or to limit_us (False)."""
            start_level = value_now()
            while clock.now_us < limit_us:
                nxt = None if sig is None else sig.next_change(clock.now_us)
                if nxt is None or nxt >= limit_us:
                    clock.advance(limit_us - clock.now_us)
                    return value_now() != start_level
                clock.advance(max(1, nxt - clock.now_us))
                if value_now() != start_level:
                    return True
            return False

        if value_now() != level and not run_until_change(clock.now_us + timeout_us):
            return -2
        start = clock.now_us
        if not run_until_change(start + timeout_us):
            return -1
        return clock.now_us - start

    class WDT:
        def __init__(self, id: int = 0, timeout: int = 5000) -> None:
            if id != 0 or timeout != 5000:
                raise ValueError("ESP8266 WDT supports only id 0 and timeout 5000")
            board.wdt_feed()

        def feed(self) -> None:
            board.wdt_feed()

    uart = FakeUART(board)

    def make_uart(num: int, baudrate: int = 115200, *args: Any, **kw: Any) -> FakeUART:
        if num != 0:
            raise ValueError(f"UART({num}) has no RX on the ESP8266; use UART(0)")
        return uart

    def reset() -> None:
        raise SimReset(HARD_RESET)

    m.Pin = Pin  # type: ignore[attr-defined]
    m.UART = make_uart  # type: ignore[attr-defined]
    m.WDT = WDT  # type: ignore[attr-defined]
    m.time_pulse_us = time_pulse_us  # type: ignore[attr-defined]
    m.unique_id = lambda: board.unique_id  # type: ignore[attr-defined]
    m.reset_cause = lambda: board.reset_cause  # type: ignore[attr-defined]
    m.reset = reset  # type: ignore[attr-defined]
    m.soft_reset = reset  # type: ignore[attr-defined]
    m.freq = lambda f=None: 80_000_000  # type: ignore[attr-defined]
    m.idle = lambda: clock.advance(100)  # type: ignore[attr-defined]
    m.disable_irq = lambda: 0  # type: ignore[attr-defined]
    m.enable_irq = lambda state=0: None  # type: ignore[attr-defined]
    for name, value in (
        ("PWRON_RESET", PWRON_RESET),
        ("HARD_RESET", HARD_RESET),
        ("WDT_RESET", WDT_RESET),
        ("SOFT_RESET", SOFT_RESET),
        ("DEEPSLEEP_RESET", DEEPSLEEP_RESET),
    ):
        setattr(m, name, value)

    o = types.ModuleType("os")
    o.dupterm = lambda stream=None, index=0: None  # type: ignore[attr-defined]
    o.urandom = lambda n: bytes(board.rng.getrandbits(8) for _ in range(n))  # type: ignore[attr-defined]
    o.listdir = lambda path="": sorted(os.listdir(board.fs_dir))  # type: ignore[attr-defined]

    s = types.ModuleType("socket")
    s.AF_INET, s.SOCK_STREAM = 2, 1  # type: ignore[attr-defined]
    s.SOL_SOCKET, s.SO_REUSEADDR = 1, 4  # type: ignore[attr-defined]
    s.socket = lambda af=2, kind=1, proto=0: FakeSocket(board, None)  # type: ignore[attr-defined]
    s.getaddrinfo = lambda host, port, *a: [(2, 1, 0, "", (host, port))]  # type: ignore[attr-defined]

    sel = types.ModuleType("select")
    sel.POLLIN, sel.POLLOUT, sel.POLLERR, sel.POLLHUP = 1, 4, 8, 16  # type: ignore[attr-defined]
    sel.poll = lambda: FakePoll(board)  # type: ignore[attr-defined]

    net = types.ModuleType("network")

    class WLAN:
        IF_STA, IF_AP = 0, 1

        def __init__(self, interface: int = 0) -> None:
            self.interface = interface
            self._active = False

        def active(self, flag: bool | None = None) -> bool:
            if flag is not None:
                self._active = bool(flag)
            return self._active

        def connect(self, ssid: str, password: str = "") -> None:
            pass

        def isconnected(self) -> bool:
            return self._active

        def config(self, *args: Any, **kw: Any) -> None:
            return None

        def ifconfig(self) -> tuple[str, str, str, str]:
            return ("127.0.0.1", "255.0.0.0", "127.0.0.1", "127.0.0.1")

    net.WLAN = WLAN  # type: ignore[attr-defined]
    net.STA_IF, net.AP_IF = 0, 1  # type: ignore[attr-defined]

    mp = types.ModuleType("micropython")
    mp.const = lambda x: x  # type: ignore[attr-defined]
    mp.alloc_emergency_exception_buf = lambda n: None  # type: ignore[attr-defined]
    mp.kbd_intr = lambda c: None  # type: ignore[attr-defined]
    mp.schedule = lambda fn, arg: fn(arg)  # type: ignore[attr-defined]

    g = types.ModuleType("gc")
    g.collect = lambda: None  # type: ignore[attr-defined]
    g.mem_free = lambda: 30_000  # type: ignore[attr-defined]
    g.mem_alloc = lambda: 8_000  # type: ignore[attr-defined]

    return {
        "time": t,
        "machine": m,
        "os": o,
        "socket": s,
        "select": sel,
        "network": net,
        "micropython": mp,
        "gc": g,
    }
