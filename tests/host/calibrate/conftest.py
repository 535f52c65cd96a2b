"""Shared builders for the calibration tests: observations from the simulator's truth."""

from __future__ import annotations

import numpy as np

from elphel_host.calibrate.detect import Corners
from elphel_host.calibrate.observations import Observations
from elphel_host.calibrate.pattern import Checkerboard
from elphel_sim.calib_rig import BoardPose, CalibRig, corner_truth, whole_board_seen
from elphel_sim.calib_target import PrintedBoard

PATTERN = Checkerboard(9, 6, 25.0)
BOARD = PrintedBoard(PATTERN)


def observe(
    rig: CalibRig,
    poses: list[BoardPose],
    *,
    noise_px: float,
    seed: int,
    seen: list[list[bool]] | None = None,
) -> Observations:
    """The true corners plus Gaussian noise, for the cameras that see each board whole."""
    rng = np.random.default_rng(seed)
    rows = []
    for k, pose in enumerate(poses):
        truth = corner_truth(rig, BOARD, pose)
        sees = whole_board_seen(rig, BOARD, pose) if seen is None else seen[k]
        rows.append(
            tuple(
                Corners(
                    t + rng.normal(0.0, noise_px, t.shape),
                    np.full(len(t), noise_px),
                    np.ones(len(t)),
                )
                if ok
                else None
                for t, ok in zip(truth, sees, strict=True)
            )
        )
    return Observations(
        PATTERN,
        (rig.size,) * len(rig.cameras),
        tuple(rows),
        tuple(f"view{k:03d}" for k in range(len(poses))),
    )


class TrueLens:
    """A simulated camera's true lens (rational model and residual) as a `quality.Lens`."""

    def __init__(self, cam: object) -> None:
        self.cam = cam
        self.width, self.height = cam.lens.width, cam.lens.height  # type: ignore[attr-defined]

    def project(self, points: np.ndarray) -> np.ndarray:
        q = self.cam.lens.project(points)  # type: ignore[attr-defined]
        return q + self.cam.residual.at(q)  # type: ignore[attr-defined]

    def rays(self, pixels: np.ndarray, *, strict: bool = True) -> np.ndarray:
        return self.cam.lens.rays(self.cam.model_pixels(pixels), strict=strict)  # type: ignore[attr-defined]
