"""The firmware's modules on the simulated ESP8266: fakes of MicroPython's own, and imports.

`build_fakes` makes ``time``, ``machine``, ``os``, ``socket``, ``select``, ``network``,
``micropython`` and ``gc`` bound to one board; `FirmwareModules` is the import system of
one boot (the fakes first, then the board's own ``.py`` files).
"""

from __future__ import annotations

import builtins
import errno
import os
import types
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from elphel_sim.micropython.clock import SimReset
from elphel_sim.micropython.links import PIN_ACCESS_US, FakePoll, FakeSocket, FakeUART

if TYPE_CHECKING:
    from elphel_sim.micropython.esp8266 import SimEsp8266

# machine.reset_cause() values
PWRON_RESET, HARD_RESET, WDT_RESET, DEEPSLEEP_RESET, SOFT_RESET = 0, 6, 1, 5, 4


class FirmwareModules:
    """The firmware's import system for one boot: fakes plus the board's .py files."""

    def __init__(self, board: SimEsp8266) -> None:
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


def build_fakes(board: SimEsp8266) -> dict[str, types.ModuleType]:
    """The fakes of MicroPython's own modules, bound to ``board``, by module name."""
    return {
        "time": fake_time(board),
        "machine": fake_machine(board),
        "os": fake_os(board),
        "socket": fake_module(
            "socket",
            AF_INET=2,
            SOCK_STREAM=1,
            SOL_SOCKET=1,
            SO_REUSEADDR=4,
            socket=lambda af=2, kind=1, proto=0: FakeSocket(board, None),
            getaddrinfo=lambda host, port, *a: [(2, 1, 0, "", (host, port))],
        ),
        "select": fake_module(
            "select", POLLIN=1, POLLOUT=4, POLLERR=8, POLLHUP=16, poll=lambda: FakePoll(board)
        ),
        "network": fake_module("network", WLAN=WLAN, STA_IF=0, AP_IF=1),
        "micropython": fake_module(
            "micropython",
            const=lambda x: x,
            alloc_emergency_exception_buf=lambda n: None,
            kbd_intr=lambda c: None,
            schedule=lambda fn, arg: fn(arg),
        ),
        "gc": fake_module(
            "gc", collect=lambda: None, mem_free=lambda: 30_000, mem_alloc=lambda: 8_000
        ),
    }


def fake_module(name: str, **attributes: Any) -> types.ModuleType:
    """A module called ``name`` holding ``attributes``."""
    module = types.ModuleType(name)
    for key, value in attributes.items():
        setattr(module, key, value)
    return module


def fake_time(board: SimEsp8266) -> types.ModuleType:
    """``time``: ticks and sleeps on the board's virtual clock (30-bit ticks)."""
    clock = board.clock
    mask = (1 << 30) - 1

    def ticks_us() -> int:
        return clock.now_us & mask

    return fake_module(
        "time",
        ticks_us=ticks_us,
        ticks_ms=lambda: (clock.now_us // 1000) & mask,
        ticks_cpu=ticks_us,
        ticks_diff=_ticks_diff,
        ticks_add=lambda a, d: (a + d) & mask,
        sleep_us=lambda us: clock.advance(max(0, int(us))),
        sleep_ms=lambda ms: clock.advance(max(0, int(ms)) * 1000),
        sleep=lambda s: clock.advance(int(s * 1_000_000)),
        time=lambda: 946684800 // 1 + clock.now_us // 1_000_000,
    )


def fake_os(board: SimEsp8266) -> types.ModuleType:
    """``os``: no REPL redirection, the board's random bytes and its filesystem folder."""
    return fake_module(
        "os",
        dupterm=lambda stream=None, index=0: None,
        urandom=lambda n: bytes(board.rng.getrandbits(8) for _ in range(n)),
        listdir=lambda path="": sorted(os.listdir(board.fs_dir)),
    )


def fake_machine(board: SimEsp8266) -> types.ModuleType:
    """``machine``: pins, pulse timing, the UART, the watchdog and resets of ``board``."""
    clock = board.clock
    uart = FakeUART(board)

    def make_uart(num: int, baudrate: int = 115200, *args: Any, **kw: Any) -> FakeUART:
        if num != 0:
            raise ValueError(f"UART({num}) has no RX on the ESP8266; use UART(0)")
        return uart

    def reset() -> None:
        raise SimReset(HARD_RESET)

    return fake_module(
        "machine",
        Pin=pin_class(board),
        UART=make_uart,
        WDT=wdt_class(board),
        time_pulse_us=time_pulse_function(board),
        unique_id=lambda: board.unique_id,
        reset_cause=lambda: board.reset_cause,
        reset=reset,
        soft_reset=reset,
        freq=lambda f=None: 80_000_000,
        idle=lambda: clock.advance(100),
        disable_irq=lambda: 0,
        enable_irq=lambda state=0: None,
        PWRON_RESET=PWRON_RESET,
        HARD_RESET=HARD_RESET,
        WDT_RESET=WDT_RESET,
        SOFT_RESET=SOFT_RESET,
        DEEPSLEEP_RESET=DEEPSLEEP_RESET,
    )


def pin_class(board: SimEsp8266) -> type:
    """``machine.Pin`` on ``board``'s simulated GPIO; each access costs virtual time."""
    clock, pins = board.clock, board.pins

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

    return Pin


def time_pulse_function(board: SimEsp8266) -> Callable[..., int]:
    """``machine.time_pulse_us`` on ``board``: the virtual clock runs to the pin's edges."""
    clock, pins = board.clock, board.pins

    def time_pulse_us(pin: Any, level: int, timeout_us: int = 1_000_000) -> int:
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

    return time_pulse_us


def wdt_class(board: SimEsp8266) -> type:
    """``machine.WDT``: feeding it feeds ``board``'s watchdog."""

    class WDT:
        def __init__(self, id: int = 0, timeout: int = 5000) -> None:
            if id != 0 or timeout != 5000:
                raise ValueError("ESP8266 WDT supports only id 0 and timeout 5000")
            board.wdt_feed()

        def feed(self) -> None:
            board.wdt_feed()

    return WDT


class WLAN:
    """``network.WLAN``: a station that is connected as soon as it is active."""

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
