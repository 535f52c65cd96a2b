"""The simulated calibration rig: its cameras, its board poses and its renders."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from elphel_host.calibrate.camera_model import rotation_vector
from elphel_host.calibrate.pattern import Checkerboard
from elphel_sim.calib_rig import BoardPose, board_poses, corner_truth, make_rig, render_grey
from elphel_sim.calib_target import PrintedBoard

BOARD = PrintedBoard(Checkerboard(9, 6, 25.0))


def test_truth_is_opencvs_projection_without_residual() -> None:
    rig = make_rig(640, 480, seed=3)
    pose = board_poses(rig, BOARD, 1, seed=4)[0]
    truth = corner_truth(rig, BOARD, pose)
    obj = BOARD.pattern.object_points_mm()
    for cam, pixels in zip(rig.cameras, truth, strict=True):
        r, t = cam.R @ pose.R, cam.R @ pose.t_mm + cam.t_mm
        theirs = cv2.projectPoints(
            obj, rotation_vector(r), t, cam.lens.camera_matrix, cam.lens.coefficients
        )[0]
        assert np.abs(pixels - theirs.reshape(-1, 2)).max() < 1e-9


def test_residual_moves_pixels_by_at_most_its_amplitude() -> None:
    flat, bent = make_rig(640, 480, seed=3), make_rig(640, 480, seed=3, residual_px=0.3)
    pose = board_poses(flat, BOARD, 1, seed=4)[0]
    moved = np.linalg.norm(
        corner_truth(bent, BOARD, pose) - corner_truth(flat, BOARD, pose), axis=-1
    )
    assert 0.05 < moved.max() <= 0.3 * np.sqrt(2) + 1e-9


def test_every_camera_sees_every_pose() -> None:
    rig = make_rig(640, 480, seed=5)
    for pose in board_poses(rig, BOARD, 6, seed=6):
        truth = corner_truth(rig, BOARD, pose)
        assert truth.min() > 0 and truth[..., 0].max() < 639 and truth[..., 1].max() < 479


def test_render_has_the_inks_where_the_truth_says() -> None:
    rig = make_rig(640, 480, seed=7, bayer=None)
    pose = board_poses(rig, BOARD, 1, seed=8)[0]
    grey = render_grey(rig.cameras[1], BOARD, pose)
    grid = corner_truth(rig, BOARD, pose)[1].reshape(6, 9, 2)
    # the middle of square (1, 1) (between corners 0, 1, 9, 10) is black, of (2, 1) white
    black = grid[:2, :2].reshape(-1, 2).mean(axis=0)
    white = grid[:2, 1:3].reshape(-1, 2).mean(axis=0)
    assert _at(grey, black) == pytest.approx(BOARD.black, abs=0.02)
    assert _at(grey, white) == pytest.approx(BOARD.white, abs=0.02)
    assert grey[0, 0] == BOARD.background


def test_a_bent_board_bulges_by_its_warp() -> None:
    rig = make_rig(640, 480, seed=3, cameras=1)
    flat = board_poses(rig, BOARD, 1, seed=4)[0]
    bent = BoardPose(flat.R, flat.t_mm, (2.0, -1.0))
    moved = np.linalg.norm(corner_truth(rig, BOARD, bent) - corner_truth(rig, BOARD, flat), axis=-1)
    assert moved.max() > 0.3


def _at(grey: np.ndarray, p: np.ndarray) -> float:
    return float(grey[round(p[1]), round(p[0])])


def test_bad_rig_requests_name_what_is_allowed() -> None:
    with pytest.raises(ValueError, match=r"1\.\.4"):
        make_rig(cameras=5)
    with pytest.raises(ValueError, match="smaller"):
        board_poses(make_rig(640, 480), BOARD, 2, seed=0, fill=(1.5, 1.6))
