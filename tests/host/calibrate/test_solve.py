"""The joint solve against the simulator's truth, and the sets it refuses."""

from __future__ import annotations

import numpy as np
import pytest

from elphel_host.calibrate.camera_model import rotation_vector
from elphel_host.calibrate.detect import Corners
from elphel_host.calibrate.observations import CalibrationInputError, Observations
from elphel_host.calibrate.quality import implied_rotation, projection_difference
from elphel_host.calibrate.solve import MARGIN, Calibration, calibrate
from elphel_sim.calib_rig import board_poses, make_rig

from .conftest import BOARD, PATTERN, TrueLens, observe

NOISE_PX = 0.01
RIG = make_rig(640, 480, seed=21)


@pytest.fixture(scope="module")
def solved() -> Calibration:
    poses = board_poses(RIG, BOARD, 24, seed=22, warp_mm=(0.6, -0.4), min_cameras=2)
    return calibrate(observe(RIG, poses, noise_px=NOISE_PX, seed=23), cross_validate=False)


def test_intrinsics_project_as_the_true_lens(solved: Calibration) -> None:
    for res, cam in zip(solved.cameras, RIG.cameras, strict=True):
        diff = projection_difference(res.lens, TrueLens(cam), margin=MARGIN)
        assert np.isfinite(diff).all()
        assert np.sqrt(np.mean(diff**2)) <= 0.02


def test_rig_within_10_urad_and_a_tenth_mm(solved: Calibration) -> None:
    # 10 urad is 0.02 px at Elphel's focal length (2045 px); these 640-px cameras see
    # 4x coarser angles, so the same 0.02 px bounds the rotation error times the focal.
    # A camera turned slightly and its principal point moved by as much are one and the
    # same to every pixel: compare the rotations each camera's pixels imply.
    turn = [
        implied_rotation(r.lens, TrueLens(c), margin=MARGIN)
        for r, c in zip(solved.cameras, RIG.cameras, strict=True)
    ]
    for k, (res, cam) in enumerate(zip(solved.cameras, RIG.cameras, strict=True)):
        seen = turn[k] @ res.R @ turn[0].T
        error_rad = np.linalg.norm(rotation_vector(seen @ cam.R.T))
        assert error_rad * cam.lens.fx <= 0.02, f"camera {k}: {error_rad * 1e6:.1f} urad"
        assert np.abs(res.t_mm - cam.t_mm).max() <= 0.1


def test_residuals_match_the_injected_noise(solved: Calibration) -> None:
    corners = sum(c.corners for c in solved.cameras)
    params = len(solved.cameras) * 18 - 6 + len(solved.views) * 6 + 2
    expected = NOISE_PX * np.sqrt(1 - params / (2 * corners))  # per axis, after the fit
    assert solved.rms_px / np.sqrt(2) == pytest.approx(expected, rel=0.1)


def test_board_bend_is_recovered(solved: Calibration) -> None:
    assert solved.warp_mm == pytest.approx((0.6, -0.4), abs=0.02)


def test_outliers_are_named() -> None:
    rig = make_rig(640, 480, cameras=1, seed=24)
    obs = observe(rig, board_poses(rig, BOARD, 8, seed=25), noise_px=NOISE_PX, seed=26)
    moved = obs.corners[3][0]
    assert moved is not None
    pixels = moved.pixels.copy()
    pixels[7] += (1.5, -1.0)
    rows = list(obs.corners)
    rows[3] = (Corners(pixels, moved.sigma_px, moved.blur_px),)
    cal = calibrate(
        Observations(obs.pattern, obs.sizes, tuple(rows), obs.view_names), cross_validate=False
    )
    assert [(o.view, o.camera, o.corner) for o in cal.outliers] == [("view003", 0, 7)]
    assert cal.rms_px < 2 * NOISE_PX


def test_too_few_views_says_how_many() -> None:
    rig = make_rig(640, 480, cameras=1, seed=27)
    obs = observe(rig, board_poses(rig, BOARD, 3, seed=28), noise_px=NOISE_PX, seed=29)
    with pytest.raises(CalibrationInputError, match="at least 4"):
        calibrate(obs)


def test_fronto_parallel_views_are_refused() -> None:
    rig = make_rig(640, 480, cameras=1, seed=30)
    obs = observe(
        rig, board_poses(rig, BOARD, 6, seed=31, max_tilt_deg=0.0), noise_px=NOISE_PX, seed=32
    )
    with pytest.raises(CalibrationInputError, match="tilted"):
        calibrate(obs)


def test_cameras_sharing_no_view_are_named() -> None:
    rig = make_rig(640, 480, seed=33)
    poses = board_poses(rig, BOARD, 10, seed=34)
    seen = [[k % 2 == 0] * 2 + [k % 2 == 1] * 2 for k in range(10)]  # cameras 0, 1 | 2, 3
    with pytest.raises(CalibrationInputError, match=r"camera\(s\) 2, 3 share no view"):
        calibrate(observe(rig, poses, noise_px=NOISE_PX, seed=35, seen=seen))


def test_views_without_a_board_are_listed() -> None:
    rig = make_rig(640, 480, cameras=1, seed=36)
    obs = observe(rig, board_poses(rig, BOARD, 7, seed=37), noise_px=NOISE_PX, seed=38)
    rows = list(obs.corners)
    rows[2] = (None,)
    cal = calibrate(
        Observations(PATTERN, obs.sizes, tuple(rows), obs.view_names), cross_validate=False
    )
    assert cal.missing == (("view002", 0),)
