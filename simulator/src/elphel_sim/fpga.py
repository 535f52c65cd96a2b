"""The camera board's FPGA: frame timing, the common trigger, and the frames it records.

The FPGA asks each port's simulated chip (`elphel_sim.chips.SimSensor`) for its timing;
the chip model knows its own registers and when a write reaches the image.

Each port's frame starts are events on one virtual timeline. In free-run a port starts its
next frame one frame period (set by its sensor's registers in effect) after the last; in
snapshot mode it starts on a trigger of the common trigger generator (camsync), after its
own delay, on every (decimate + 1)-th trigger, once the sensor is ready again; a frame's
timestamp is then the trigger time, the same on every port. In photo-finish a frame is a
composite of strips, each strip one sensor frame. At each frame start the sensor latches
the register writes due, and the frame is recorded with the register state in effect; its
image is formed from that record (by the chip and the renderer, `elphel_sim.render`) only
when someone asks for it (ring buffer, lazily).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from elphel_sim.world import FloatArray, Pose

RING_FRAMES = 64
CAMSYNC_HZ = 100_000_000  # TRIG_PERIOD and TRIG_DELAY count 10 ns ticks


@dataclass
class Camsync:
    """The common trigger generator: a period, started at a time; 0 = stopped, 1 = single."""

    period_10ns: int = 0
    start_s: float = 0.0

    def program(self, period_10ns: int, now_s: float) -> None:
        if period_10ns != self.period_10ns:
            self.period_10ns = period_10ns
            self.start_s = now_s

    def next_trigger(self, after_s: float, *, every: int) -> float | None:
        """First trigger at or after ``after_s`` whose index is a multiple of ``every``."""
        if self.period_10ns == 0:
            return None
        if self.period_10ns == 1:  # a single trigger at the moment it was programmed
            return self.start_s if self.start_s >= after_s - 1e-12 else None
        period_s = self.period_10ns / CAMSYNC_HZ
        k = max(0, math.ceil((after_s - self.start_s) / period_s - 1e-9))
        k = ((k + every - 1) // every) * every
        return self.start_s + k * period_s


@dataclass
class FrameRecord:
    """What the FPGA knows of one frame: enough to form its image later."""

    port: int
    frame: int
    start_s: float
    timestamp_ns: int
    registers: dict[str, int]
    pose: Pose
    carriage_mm: float
    strips: int  # 0 = a normal frame; else photo-finish strips in this composite
    strip_period_s: float
    image: NDArray[np.uint16] | None = None

    def strip_times_s(self) -> FloatArray:
        """Start time of each strip of the frame (one entry for a normal frame)."""
        strips = max(self.strips, 1)
        times: FloatArray = self.start_s + self.strip_period_s * np.arange(
            strips, dtype=np.float64
        )
        return times


@dataclass
class PortFPGA:
    """Per-port FPGA settings (programmed by the daemon through the board) and frame state."""

    snapshot: bool = False
    delay_10ns: int = 0
    decimate: int = 0
    pf_strips: int = 0
    frame: int = 0
    last_start_s: float = 0.0
    busy_until_s: float = 0.0
    next_start_s: float = 0.0
    next_timestamp_s: float = 0.0
    pending: list[tuple[int, str, int]] = field(default_factory=list)
    ring: deque[FrameRecord] = field(default_factory=lambda: deque(maxlen=RING_FRAMES))
