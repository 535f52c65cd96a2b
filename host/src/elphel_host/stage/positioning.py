"""Calibration, backlash measurement and caliper closed-loop positioning.

The caliper frame is the user's millimetre frame: a position in mm is what the caliper
shows there. The model maps steps to mm as ``offset_mm + steps * mm_per_step`` for a
carriage that arrived moving towards +steps; approaching from the other side adds the
backlash. Every position this module reports was read from the caliper after the motion
ended; a move whose caliper change does not match the steps raises StageStallError.
"""

from __future__ import annotations

import statistics
from collections.abc import Callable
from dataclasses import dataclass, field

from elphel_host.errors import (
    StageClosedLoopError,
    StageLimitError,
    StageNotHomedError,
    StageStallError,
)
from elphel_host.stage.client import StageClient
from elphel_host.stage.model import StageModel

CALIPER_LSB_MM = 0.01
# How far one confirmed reading can lie from the carriage: half an LSB plus display noise.
READING_ERROR_MM = CALIPER_LSB_MM / 2 + 0.002


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
    def read_mm(self, samples: int = 1) -> float:
        """The caliper in mm: the mean of `samples` fresh confirmed readings."""
        if samples < 1:
            raise ValueError(f"samples {samples}; need at least 1")
        return statistics.fmean(self.client.read_caliper_um() for _ in range(samples)) / 1000.0

    def _goto(self, steps: int, samples: int = 1) -> float:
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
        now_mm = self.read_mm(samples)
        self._verified = None
        if start_mm is not None:
            expected = (steps - before.steps) * self.model.mm_per_step
            moved = now_mm - start_mm
            slack = (
                self.stall_tolerance_mm
                + self.model.backlash_mm
                + abs(expected) * 0.01
                + 2 * READING_ERROR_MM  # the move is the difference of two readings
            )
            if abs(moved - expected) > slack:
                raise StageStallError(
                    f"caliper moved {moved:+.3f} mm for {steps - before.steps:+d} steps "
                    f"(expected {expected:+.3f} mm, allowed ±{slack:.3f}): "
                    "motor stalled or lost steps"
                )
        self._verified = (steps, now_mm)
        return now_mm

    def _approach(self, steps: int, overshoot_steps: int, samples: int = 1) -> float:
        """Reach `steps` moving towards +steps (from below), so backlash is taken up."""
        st = self.client.status()
        if st.steps >= steps or self.last_dir <= 0:
            lo, _hi = self.client.limits_steps()
            self._goto(max(lo, steps - overshoot_steps))
        return self._goto(steps, samples)

    # ---- calibration -------------------------------------------------------------------
    def calibrate(
        self,
        *,
        span_mm: float = 80.0,
        start_mm: float = 10.0,
        repeats: int = 3,
        home_first: bool = True,
        readings: int = 4,
        progress: Callable[[int, int, str], None] | None = None,
    ) -> Calibration:
        """Measure mm/step: long moves approached from one side, repeated.

        Each end of a run is the mean of `readings` caliper readings, so a frame's display
        noise does not land whole in the run's mm/step. ``progress(done, total, message)``
        is called before the first run and after each (else each run is logged).
        """
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
        report = progress or (lambda done, total, message: self.log(message))
        if progress is not None:
            progress(0, repeats, f"0/{repeats} runs")
        for i in range(repeats):
            c0 = self._approach(s0, overshoot, readings)
            c1 = self._goto(s1, readings)
            mps = (c1 - c0) / (s1 - s0)
            runs.append(mps)
            points.extend([(s0, c0), (s1, c1)])
            report(i + 1, repeats, f"run {i + 1}/{repeats}: {mps:.7f} mm/step")
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
    def travel_mm(self) -> tuple[float, float]:
        """The soft limits in the caliper's millimetres, by the model (needs a reference)."""
        self._require_reference()
        lo, hi = self.client.limits_steps()
        return self.model.mm_at(lo), self.model.mm_at(hi)

    def check_travel(self, *targets_mm: float, slack_mm: float = CALIPER_LSB_MM) -> None:
        """Raise `StageLimitError` in millimetres if a target lies beyond the travel."""
        lo_mm, hi_mm = self.travel_mm()
        for target in targets_mm:
            if not lo_mm - slack_mm <= target <= hi_mm + slack_mm:
                raise StageLimitError(
                    f"{mm_text(target)} mm is beyond the travel "
                    f"{mm_text(lo_mm)}..{mm_text(hi_mm)} mm",
                    code=15,
                    keyword="MOVE",
                )

    def move_open_loop(self, target_mm: float) -> MoveResult:
        """Move by the model only (one move from wherever the carriage is)."""
        self.check_travel(target_mm)
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
        fit_steps: int = 6,
        verify_readings: int = 3,
    ) -> MoveResult:
        """Approach the target from below, fit the local offset, stop at the nearest step.

        A single caliper reading cannot tell which step is nearest the target: it is
        quantised to 0.01 mm and one step (about 0.0088 mm) moves the carriage by a little
        less than that, so stepping against single readings can cycle without settling.
        Instead the carriage comes up from below (backlash taken up) and creeps the last
        `fit_steps` steps one at a time with a reading at each. Consecutive steps put the
        carriage at phases spread across the caliper LSB, so the mean of ``reading -
        steps * mm_per_step`` over them (each step's readings averaged first) estimates the
        local offset to a small fraction of an LSB, and more readings only improve it.

        The carriage creeps on to the step the fit puts nearest the target, or comes up to
        it again from below if the fit puts it lower (with a fresh window if the model was
        more than `fit_steps` off), and is read `verify_readings` times there. The move
        ends when the fit still picks that step and the mean of the readings since arriving
        is within LSB/2 + `tolerance_mm` of the target; otherwise more readings are taken,
        up to `max_iterations` checks. ``MoveResult.caliper_mm`` is that mean.
        """
        if fit_steps < 2 or verify_readings < 1:
            raise ValueError(
                f"fit_steps {fit_steps}, verify_readings {verify_readings}; "
                "need fit_steps >= 2 and verify_readings >= 1"
            )
        self.check_travel(target_mm, slack_mm=CALIPER_LSB_MM / 2 + tolerance_mm)
        m = self.model
        assert m.offset_mm is not None
        overshoot = max(10, round((approach_mm + m.backlash_mm) / m.mm_per_step))
        fit = _StepFit(target_mm, m.mm_per_step)
        lo, hi = self.client.limits_steps()

        def start_window(goal: int) -> int:
            return self._start_window(fit, goal, (lo, hi), fit_steps, overshoot)

        steps = start_window(fit.nearest(m.offset_mm))
        needed = verify_readings
        iterations = 0
        while True:
            steps, best = self._creep(fit, steps, hi, fit_steps)
            iterations += 1
            if iterations > max_iterations:
                raise fit.failed(steps, max_iterations, tolerance_mm)
            if abs(best - steps) > fit_steps:
                # The model was far off here: fit again next to the target.
                steps = start_window(best)
                continue
            if max(lo, best) < steps:
                # The fit puts the target lower: come up to it again from below.
                steps = max(lo, best)
                fit.record(steps, self._approach(steps, overshoot), moved=True)
                continue
            while len(fit.arrived) < needed:
                fit.record(steps, self.read_mm(), moved=False)
            offset = fit.offset()
            caliper_mm = statistics.fmean(fit.arrived)
            if steps == lo:
                fit.check_reachable(caliper_mm, CALIPER_LSB_MM / 2 + tolerance_mm)
            if min(max(lo, fit.nearest(offset)), hi) == steps and (
                abs(caliper_mm - target_mm) <= CALIPER_LSB_MM / 2 + tolerance_mm
            ):
                self.last_dir = 1
                at_mm = offset + steps * m.mm_per_step
                return MoveResult(target_mm, caliper_mm, steps, iterations, at_mm)
            needed = len(fit.arrived) + verify_readings

    def _start_window(
        self, fit: _StepFit, goal: int, limits: tuple[int, int], fit_steps: int, overshoot: int
    ) -> int:
        """Come up from below to the first step of a fit window ending at ``goal``."""
        fit.by_step.clear()
        first = min(max(limits[0], goal - fit_steps + 1), limits[1] - fit_steps)
        fit.record(first, self._approach(first, overshoot), moved=True)
        return first

    def _creep(self, fit: _StepFit, steps: int, hi: int, fit_steps: int) -> tuple[int, int]:
        """Step up one at a time, reading each, while the fit wants it: (steps, best step)."""
        best = fit.nearest(fit.offset())
        while steps < hi and (len(fit.by_step) < fit_steps or steps < best <= steps + fit_steps):
            steps += 1
            fit.record(steps, self._goto(steps), moved=True)
            best = fit.nearest(fit.offset())
        return steps, best

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


@dataclass
class _StepFit:
    """The readings of a closed-loop move: per step (all arrived from below), and since arriving."""

    target_mm: float
    mm_per_step: float
    by_step: dict[int, list[float]] = field(default_factory=dict)
    arrived: list[float] = field(default_factory=list)

    def offset(self) -> float:
        """The local offset: mean of ``reading - steps * mm_per_step``, each step averaged."""
        mps = self.mm_per_step
        return statistics.fmean(statistics.fmean(r) - s * mps for s, r in self.by_step.items())

    def nearest(self, offset: float) -> int:
        """The step nearest the target under ``offset``."""
        return round((self.target_mm - offset) / self.mm_per_step)

    def record(self, at: int, reading: float, *, moved: bool) -> None:
        if moved:
            self.arrived.clear()
        self.arrived.append(reading)
        self.by_step.setdefault(at, []).append(reading)

    def check_reachable(self, lowest_mm: float, slack_mm: float) -> None:
        """Refuse a target below ``lowest_mm``, where the lowest step puts the carriage."""
        if self.target_mm < lowest_mm - slack_mm:
            raise StageLimitError(
                f"{mm_text(self.target_mm)} mm is beyond the travel: at the end of the "
                f"travel the caliper reads {mm_text(lowest_mm)} mm",
                code=15,
                keyword="MOVE",
            )

    def failed(self, steps: int, max_iterations: int, tolerance_mm: float) -> StageClosedLoopError:
        return StageClosedLoopError(
            f"closed-loop move to {self.target_mm:.4f} mm: caliper reads "
            f"{statistics.fmean(self.arrived):.4f} mm at step {steps} after "
            f"{max_iterations} corrections (tolerance ±{tolerance_mm} mm beyond half "
            f"the {CALIPER_LSB_MM} mm caliper LSB)"
        )


def mm_text(mm: float) -> str:
    """A position for people: to 0.01 mm, without trailing zeros (``118``, ``42.5``)."""
    text = f"{round(mm, 2):.2f}".rstrip("0").rstrip(".")
    return "0" if text == "-0" else text
