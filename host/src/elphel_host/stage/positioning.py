"""Calibration, backlash measurement and caliper closed-loop positioning.

The caliper frame is the user's millimetre frame: a position in mm is what the caliper
shows there. The model maps steps to mm as ``offset_mm + steps * mm_per_step`` for a
carriage that arrived moving towards +steps; approaching from the other side adds the
backlash. Every position this module reports was read from the caliper after the motion
ended; a move whose caliper change does not match the steps raises StageStallError.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from elphel_host.errors import (
    StageClosedLoopError,
    StageLimitError,
    StageNotHomedError,
    StageStallError,
)
from elphel_host.stage.client import NOMINAL_MM_PER_STEP, StageClient

CALIPER_LSB_MM = 0.01


@dataclass(frozen=True)
class Calibration:
    mm_per_step: float
    spread_mm_per_step: float  # sample standard deviation of the runs
    runs: tuple[float, ...]
    offset_mm: float  # caliper mm at step 0 after a +approach
    span_mm: float


@dataclass(frozen=True)
class MoveResult:
    target_mm: float
    caliper_mm: float  # verified position: the caliper after the move
    steps: int
    iterations: int
    estimate_mm: float  # model estimate of where the carriage is (sub-LSB)


@dataclass
class StageModel:
    mm_per_step: float = NOMINAL_MM_PER_STEP
    offset_mm: float | None = None
    backlash_mm: float = 0.0
    calibrated: bool = False
    spread_mm_per_step: float = math.nan
    readings: list[tuple[int, float]] = field(default_factory=list)

    def steps_for(self, mm: float) -> float:
        if self.offset_mm is None:
            raise StageNotHomedError(
                "no caliper reference yet: read the caliper at a known step first"
            )
        return (mm - self.offset_mm) / self.mm_per_step

    def mm_at(self, steps: int) -> float:
        if self.offset_mm is None:
            raise StageNotHomedError("no caliper reference yet")
        return self.offset_mm + steps * self.mm_per_step


class Positioner:
    """Stage motion in millimetres, verified by the caliper."""

    def __init__(
        self,
        client: StageClient,
        model: StageModel | None = None,
        *,
        move_timeout_s: float = 120.0,
        stall_tolerance_mm: float = 0.06,
        log: Callable[[str], None] | None = None,
    ) -> None:
        self.client = client
        self.model = model or StageModel()
        self.move_timeout_s = move_timeout_s
        self.stall_tolerance_mm = stall_tolerance_mm
        self.log = log or (lambda msg: None)
        self.last_dir = 0  # +1 if the carriage last moved towards +steps
        self._verified: tuple[int, float] | None = None  # (steps, caliper mm) after a move

    # ---- verified primitives ---------------------------------------------------------
    def read_mm(self) -> float:
        return self.client.read_caliper_um() / 1000.0

    def _goto(self, steps: int) -> float:
        """Move to `steps`, wait, read the caliper, check the move really happened."""
        before = self.client.status()
        if not before.homed:
            raise StageNotHomedError("stage position unknown: home it (elphel stage home) first")
        lo, hi = self.client.limits_steps()
        if not lo <= steps <= hi:
            raise StageLimitError(
                f"target step {steps} outside soft limits {lo}..{hi}", code=15, keyword="MOVE"
            )
        start_mm = None
        if steps != before.steps:
            known = self._verified
            start_mm = (
                known[1] if known is not None and known[0] == before.steps else self.read_mm()
            )
        if steps != before.steps:
            self.client.move_to_steps(steps).wait(self.move_timeout_s)
            self.last_dir = 1 if steps > before.steps else -1
        now_mm = self.read_mm()
        self._verified = None
        if start_mm is not None:
            expected = (steps - before.steps) * self.model.mm_per_step
            moved = now_mm - start_mm
            slack = self.stall_tolerance_mm + self.model.backlash_mm + abs(expected) * 0.01
            if abs(moved - expected) > slack:
                raise StageStallError(
                    f"caliper moved {moved:+.3f} mm for {steps - before.steps:+d} steps "
                    f"(expected {expected:+.3f} mm, allowed ±{slack:.3f}): "
                    "motor stalled or lost steps"
                )
        self._verified = (steps, now_mm)
        return now_mm

    def _approach(self, steps: int, overshoot_steps: int) -> float:
        """Reach `steps` moving towards +steps (from below), so backlash is taken up."""
        st = self.client.status()
        if st.steps >= steps or self.last_dir <= 0:
            lo, _hi = self.client.limits_steps()
            self._goto(max(lo, steps - overshoot_steps))
        return self._goto(steps)

    # ---- calibration -------------------------------------------------------------------
    def calibrate(
        self,
        *,
        span_mm: float = 80.0,
        start_mm: float = 10.0,
        repeats: int = 3,
        home_first: bool = True,
    ) -> Calibration:
        """Measure mm/step: long moves approached from one side, repeated."""
        if repeats < 2:
            raise ValueError(f"repeats {repeats}; need at least 2 for a spread")
        st = self.client.status()
        if not st.homed:
            if not home_first:
                raise StageNotHomedError("calibration needs a homed stage; run `elphel stage home`")
            self.log("homing")
            self.client.home().wait(self.move_timeout_s)
        nominal = self.model.mm_per_step
        s0 = round(start_mm / nominal)
        s1 = s0 + round(span_mm / nominal)
        lo, hi = self.client.limits_steps()
        if s0 - 100 < lo or s1 > hi:
            raise StageLimitError(
                f"calibration span steps {s0}..{s1} does not fit soft limits {lo}..{hi}; "
                "use a smaller span_mm or start_mm",
                code=15,
                keyword="MOVE",
            )
        overshoot = max(20, round(0.3 / nominal))
        runs: list[float] = []
        points: list[tuple[int, float]] = []
        for i in range(repeats):
            c0 = self._approach(s0, overshoot)
            c1 = self._goto(s1)
            mps = (c1 - c0) / (s1 - s0)
            runs.append(mps)
            points.extend([(s0, c0), (s1, c1)])
            self.log(f"run {i + 1}/{repeats}: {mps:.7f} mm/step")
            self.last_dir = 1
        mean = statistics.fmean(runs)
        spread = statistics.stdev(runs)
        offset = statistics.fmean(c - s * mean for s, c in points)
        self.model.mm_per_step = mean
        self.model.spread_mm_per_step = spread
        self.model.offset_mm = offset
        self.model.calibrated = True
        return Calibration(mean, spread, tuple(runs), offset, span_mm)

    def measure_backlash(
        self, *, at_mm: float | None = None, travel_mm: float = 1.0, repeats: int = 4
    ) -> float:
        """Backlash in mm: the same step position reached from below and from above."""
        self._require_reference()
        m = self.model
        base = m.steps_for(at_mm) if at_mm is not None else self.client.status().steps
        d = max(20, round(travel_mm / m.mm_per_step))
        overshoot = max(20, round(0.3 / m.mm_per_step))
        values = []
        for i in range(repeats):
            p = round(base) + i * 7  # sub-LSB phases differ between repeats
            up = self._approach(p, overshoot)
            self._goto(p + d)
            down = self._goto(p)
            values.append(down - up)
            self.last_dir = -1
        backlash = max(0.0, statistics.fmean(values))
        m.backlash_mm = backlash
        return backlash

    def _require_reference(self) -> None:
        if self.model.offset_mm is None:
            st = self.client.status()
            if not st.homed:
                raise StageNotHomedError(
                    "stage position unknown: home it (elphel stage home) first"
                )
            self.model.offset_mm = self.read_mm() - st.steps * self.model.mm_per_step

    # ---- moves in mm -------------------------------------------------------------------
    def move_open_loop(self, target_mm: float) -> MoveResult:
        """Move by the model only (one move from wherever the carriage is)."""
        self._require_reference()
        steps = round(self.model.steps_for(target_mm))
        caliper = self._goto(steps)
        return MoveResult(target_mm, caliper, steps, 1, self.model.mm_at(steps))

    def move_closed_loop(
        self,
        target_mm: float,
        *,
        tolerance_mm: float = 0.005,
        max_iterations: int = 8,
        approach_mm: float = 0.15,
    ) -> MoveResult:
        """Approach the target from below and correct with caliper readings.

        Each caliper reading r taken after a +approach at step s bounds the carriage to
        r ± LSB/2, so ``offset`` lies in an interval; readings at several nearby steps
        narrow it below one caliper LSB. The move ends at the step whose estimate is
        nearest the target once the caliper agrees (|r - target| <= LSB/2 + tolerance).
        """
        self._require_reference()
        m = self.model
        mps = m.mm_per_step
        half = CALIPER_LSB_MM / 2 + 0.002  # quantisation plus caliper noise
        overshoot = max(10, round((approach_mm + m.backlash_mm) / mps))
        lo_off, hi_off = -math.inf, math.inf

        def constrain(reading: float, steps: int) -> tuple[float, float]:
            nonlocal lo_off, hi_off
            a, b = reading - half - steps * mps, reading + half - steps * mps
            if a > hi_off or b < lo_off:  # inconsistent with older readings: local restart
                lo_off, hi_off = a, b
            else:
                lo_off, hi_off = max(lo_off, a), min(hi_off, b)
            return lo_off, hi_off

        goal = round(m.steps_for(target_mm))
        pre = goal - overshoot
        reading = self._approach(pre, overshoot)
        steps = pre
        constrain(reading, steps)
        iterations = 0
        while True:
            iterations += 1
            if iterations > max_iterations:
                raise StageClosedLoopError(
                    f"closed-loop move to {target_mm:.4f} mm: caliper reads {reading:.3f} mm after "
                    f"{max_iterations} corrections (tolerance ±{tolerance_mm} mm beyond the "
                    f"{CALIPER_LSB_MM} mm caliper LSB)"
                )
            offset = (lo_off + hi_off) / 2
            goal = round((target_mm - offset) / mps)
            if goal < steps:
                # Overshot: go back below and come up again.
                reading = self._approach(goal - 2, overshoot)
                steps = goal - 2
                constrain(reading, steps)
                continue
            # Creep the last few steps one at a time: each reading narrows the offset.
            for s in range(max(steps + 1, goal - 3), goal + 1):
                reading = self._goto(s)
                steps = s
                constrain(reading, steps)
            offset = (lo_off + hi_off) / 2
            best = round((target_mm - offset) / mps)
            if best == steps and abs(reading - target_mm) <= CALIPER_LSB_MM / 2 + tolerance_mm:
                m.offset_mm = offset  # refresh the model locally
                self.last_dir = 1
                return MoveResult(target_mm, reading, steps, iterations, offset + steps * mps)
            if best > steps:
                continue
            if best < steps:
                reading = self._approach(best - 3, overshoot)
                steps = best - 3
                constrain(reading, steps)

    # ---- recovery -------------------------------------------------------------------------
    def resync_from_caliper(self) -> int:
        """After a reset: declare the step position the caliper implies (needs a model)."""
        if self.model.offset_mm is None:
            raise StageNotHomedError("no calibration to re-sync from; home the stage")
        reading = self.read_mm()
        steps = round((reading - self.model.offset_mm) / self.model.mm_per_step)
        self.client.declare_position_steps(steps)
        self.last_dir = 0  # backlash side unknown: next move approaches from below
        return steps


def wait_idle(client: StageClient, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while client.status().moving:
        if time.monotonic() > deadline:
            from elphel_host.errors import StageTimeout

            raise StageTimeout(f"stage still moving after {timeout_s} s")
        time.sleep(0.01)
