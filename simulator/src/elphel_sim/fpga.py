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
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from elphel_camd.params import TRIG_SNAPSHOT, TRIGGERMODE, TRIGSEQ, WINDOW
from elphel_sim.world import FloatArray, Pose

if TYPE_CHECKING:
    from elphel_sim.calib_board import BoardState
    from elphel_sim.chips.sensor import SensorTiming

RING_FRAMES = 64
CAMSYNC_HZ = 100_000_000  # TRIG_PERIOD and TRIG_DELAY count 10 ns ticks
CAMSYNC = "camsync"  # a pending setting of the common trigger generator (its period)


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
    board: BoardState | None = None  # the calibration board at the frame's start

    def strip_times_s(self) -> FloatArray:
        """Start time of each strip of the frame (one entry for a normal frame)."""
        strips = max(self.strips, 1)
        times: FloatArray = self.start_s + self.strip_period_s * np.arange(strips, dtype=np.float64)
        return times


@dataclass(frozen=True)
class PortSettings:
    """A port's FPGA settings, as programmed by the daemon through the board."""

    snapshot: bool = False  # start frames on the common trigger
    delay_10ns: int = 0
    decimate: int = 0
    pf_strips: int = 0  # photo-finish strips per composite frame (0: normal frames)


@dataclass
class PortFPGA:
    """One port's frame clock: its settings in effect, pending settings and recent frames.

    A setting programmed for frame N is pending until frame N starts (per-register
    latency); `apply_due` puts the due ones in effect at each frame start.
    """

    settings: PortSettings = field(default_factory=PortSettings)
    frame: int = 0
    last_start_s: float = 0.0
    busy_until_s: float = 0.0
    next_start_s: float = 0.0
    next_timestamp_s: float = 0.0
    pending: list[tuple[int, str, int]] = field(default_factory=list)
    ring: deque[FrameRecord] = field(default_factory=lambda: deque(maxlen=RING_FRAMES))

    def program(self, port: int, function: str, state: Mapping[str, int]) -> None:
        """Queue the FPGA side of a parameter function of port ``port`` for its target frame.

        The port whose number is TRIG_MASTER also programs the common trigger's period.
        """
        target = state.get("FRAME", 0)
        if function == TRIGSEQ:
            self.pending.append((target, "delay_10ns", state["TRIG_DELAY"]))
            self.pending.append((target, "decimate", state["TRIG_DECIMATE"]))
            if port == state["TRIG_MASTER"]:
                self.pending.append((target, CAMSYNC, state["TRIG_PERIOD"]))
        elif function == TRIGGERMODE:
            self.pending.append((target, "snapshot", int(bool(state["TRIG"] & TRIG_SNAPSHOT))))
        elif function == WINDOW:
            pf = state["PF_HEIGHT"]
            self.pending.append((target, "pf_strips", state["WOI_HEIGHT"] // pf if pf else 0))

    def apply_due(self) -> list[int]:
        """Put the settings due by the current frame in effect.

        Returns the trigger periods (10 ns) due for the common trigger generator, in the
        order they were programmed; the board programs them (they concern every port).
        """
        due = [p for p in self.pending if p[0] <= self.frame]
        self.pending = [p for p in self.pending if p[0] > self.frame]
        periods = []
        for _, key, value in due:
            if key == CAMSYNC:
                periods.append(value)
            else:
                change: dict[str, Any] = {key: bool(value) if key == "snapshot" else value}
                self.settings = replace(self.settings, **change)
        return periods

    def schedule_next(
        self, timing: SensorTiming, *, sensor_snapshot: bool, camsync: Camsync, now_s: float
    ) -> None:
        """When the next frame starts, from the sensor's timing and the settings in effect."""
        settings = self.settings
        strips = max(settings.pf_strips, 1)
        if settings.snapshot and sensor_snapshot:
            every = settings.decimate + 1
            ready = max(self.busy_until_s, now_s if self.frame else 0.0)
            delay_s = settings.delay_10ns / 1e8
            trigger = camsync.next_trigger(ready - delay_s, every=every)
            if trigger is None:
                self.next_start_s = math.inf
            else:
                self.next_start_s = trigger + delay_s
                self.next_timestamp_s = trigger
        else:
            start = self.last_start_s + timing.frame_s * strips if self.frame else 0.0
            self.next_start_s = start
            self.next_timestamp_s = start

    def start_frame(self) -> float:
        """The next frame starts: count it and return its start time."""
        self.frame += 1
        self.last_start_s = self.next_start_s
        return self.last_start_s

    def strip_period_s(
        self, timing: SensorTiming, *, sensor_snapshot: bool, camsync: Camsync
    ) -> float:
        """Time between the strips of the frame just started (a frame period if free-run).

        Also marks the sensor busy until the frame's last strip is read out.
        """
        settings = self.settings
        strips = settings.pf_strips
        if strips and settings.snapshot and sensor_snapshot and camsync.period_10ns > 1:
            period_s = camsync.period_10ns * (settings.decimate + 1) / 1e8
        else:
            period_s = timing.frame_s
        self.busy_until_s = self.last_start_s + timing.busy_s + period_s * max(strips - 1, 0)
        return period_s
