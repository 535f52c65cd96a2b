"""Closed-loop positioning against a fast stand-in stage: the algorithm, not the link.

The stand-in has the simulated rig's mechanics (0.008778 mm/step, 0.05 mm backlash,
periodic lead error) and a caliper with a 0.01 mm LSB and 0.002 mm display noise, so a
step moves the carriage by 0.88 LSB and single readings beat against the steps: the
situation that made the earlier creep-and-compare loop give up near some targets.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

import pytest

from elphel_host.stage import Positioner, StageModel

MM_PER_STEP = 0.008778
BACKLASH_MM = 0.05
OFFSET_MM = 0.84  # caliper mm at step 0 (+approach), before lead error


@dataclass
class Status:
    steps: int
    homed: bool = True
    moving: bool = False
    state: str = "IDLE"


class Handle:
    def wait(self, timeout: float | None = None) -> None:
        return None


class StandInStage:
    """Just the client calls `Positioner` makes, answered from a mechanical model."""

    def __init__(self, seed: int, *, frame_mean: bool) -> None:
        self.rng = random.Random(seed)
        self.frame_mean = frame_mean  # CAL? reports the mean of its two frames, or the last
        self.steps = 0
        self.carriage_mm = self._nut_mm(0) - BACKLASH_MM / 2

    @staticmethod
    def _nut_mm(steps: int) -> float:
        x = OFFSET_MM + BACKLASH_MM / 2 + steps * MM_PER_STEP
        return x + 0.004 * math.sin(2 * math.pi * x / 5.0)

    def status(self) -> Status:
        return Status(self.steps)

    def limits_steps(self) -> tuple[int, int]:
        return 0, 13465

    def move_to_steps(self, target: int) -> Handle:
        # A monotonic move ends with the nut pushing the carriage, or inside the play.
        nut, half = self._nut_mm(target), BACKLASH_MM / 2
        if nut - self.carriage_mm > half:
            self.carriage_mm = nut - half
        elif self.carriage_mm - nut > half:
            self.carriage_mm = nut + half
        self.steps = target
        return Handle()

    def _frame_um(self) -> int:
        return 10 * round((self.carriage_mm + self.rng.gauss(0.0, 0.002)) * 100)

    def read_caliper_um(self) -> int:
        frames = [self._frame_um(), self._frame_um()]
        return round(sum(frames) / 2) if self.frame_mean else frames[-1]


@pytest.mark.parametrize("frame_mean", [True, False], ids=["mean-of-frames", "last-frame"])
def test_closed_loop_lands_within_a_hundredth_of_every_target(frame_mean):
    stage = StandInStage(seed=1, frame_mean=frame_mean)
    # A calibrated model: mm/step 0.03 % off, offset off by the lead error and more.
    model = StageModel(
        mm_per_step=MM_PER_STEP * 1.0003, offset_mm=OFFSET_MM + 0.006, backlash_mm=BACKLASH_MM
    )
    pos = Positioner(stage, model)  # type: ignore[arg-type]
    rng = random.Random(2026)
    targets = [71.7909, *(rng.uniform(3.0, 115.0) for _ in range(300))]
    worst = 0.0
    for t in targets:
        r = pos.move_closed_loop(t)
        error = abs(stage.carriage_mm - t)
        worst = max(worst, error)
        assert error <= 0.01, (t, stage.carriage_mm, r)
        assert abs(r.caliper_mm - stage.carriage_mm) <= 0.011, (t, r)
        assert r.steps == stage.steps
        assert abs(r.estimate_mm - stage.carriage_mm) <= 0.005, (t, r)
    print(f"closed loop over {len(targets)} targets: worst {worst:.4f} mm")


def test_closed_loop_recovers_from_a_model_far_off():
    stage = StandInStage(seed=3, frame_mean=True)
    model = StageModel(mm_per_step=MM_PER_STEP * 1.003, offset_mm=OFFSET_MM - 0.3)
    pos = Positioner(stage, model)  # type: ignore[arg-type]
    for t in (12.5, 60.0, 101.25):
        r = pos.move_closed_loop(t)
        assert abs(stage.carriage_mm - t) <= 0.01 and r.iterations <= 8
