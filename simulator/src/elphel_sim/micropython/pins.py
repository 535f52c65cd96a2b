"""GPIO of the simulated board: firmware-driven outputs and simulator-driven inputs."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol


class Signal(Protocol):
    """A level the simulated world drives onto an input pin."""

    def level_at(self, t_us: int) -> int:
        """Logic level at virtual time t_us."""
        ...

    def next_change(self, t_us: int) -> int | None:
        """Earliest time > t_us at which the level may change, or None if never (or unknown)."""
        ...


class FunctionSignal:
    """A level computed from the world when read (limit switches); polled, no edge times."""

    def __init__(self, fn: Callable[[], int]) -> None:
        self.fn = fn

    def level_at(self, t_us: int) -> int:
        return self.fn()

    def next_change(self, t_us: int) -> int | None:
        return t_us + 20  # unknown: look again in 20 us


OutputListener = Callable[[int, int], None]  # (level, t_us)


class PinBank:
    """All GPIO: inputs read a Signal, outputs notify listeners on every write."""

    VALID = (0, 1, 2, 3, 4, 5, 12, 13, 14, 15, 16)

    def __init__(self) -> None:
        self.inputs: dict[int, Signal] = {}
        self.outputs: dict[int, int] = {}
        self.listeners: dict[int, list[OutputListener]] = {}

    def check(self, num: int) -> None:
        if num not in self.VALID:
            raise ValueError(f"GPIO{num} is not usable on the ESP8266; allowed {self.VALID}")

    def attach_input(self, num: int, signal: Signal) -> None:
        self.inputs[num] = signal

    def listen(self, num: int, fn: OutputListener) -> None:
        self.listeners.setdefault(num, []).append(fn)

    def write(self, num: int, level: int, t_us: int) -> None:
        level = 1 if level else 0
        self.outputs[num] = level
        for fn in self.listeners.get(num, ()):
            fn(level, t_us)

    def read(self, num: int, t_us: int, is_output: bool) -> int:
        if is_output:
            return self.outputs.get(num, 0)
        sig = self.inputs.get(num)
        return 1 if sig is None else sig.level_at(t_us)  # unconnected: pull-up
