"""Corner detection on the simulator's board views, against the simulator's truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from elphel_host.calibrate.camera_model import rotation_matrix
from elphel_host.calibrate.detect import detect, grey_image
from elphel_host.calibrate.pattern import Checkerboard
from elphel_sim.calib_rig import BoardPose, board_poses, corner_truth, make_rig, render_view
from elphel_sim.calib_target import PrintedBoard

PATTERN = Checkerboard(9, 6, 25.0)
BOARD = PrintedBoard(PATTERN)


@pytest.fixture(scope="module")
def views() -> list[tuple[np.ndarray, np.ndarray]]:
    """(raw Bayer image, true corners) for 2 cameras x 2 views at the default noise and blur."""
    rig = make_rig(640, 480, cameras=2, seed=11)
    out = []
    for k, pose in enumerate(board_poses(rig, BOARD, 2, seed=12)):
        images = render_view(rig, BOARD, pose, seed=100 + k)
        out += list(zip(images, corner_truth(rig, BOARD, pose), strict=True))
    return out


def _opencv_corners(image: np.ndarray, truth: np.ndarray) -> np.ndarray | None:
    grey = grey_image(image, "GRBG")
    found, corners = cv2.findChessboardCornersSB(
        np.clip(grey * (255 / grey.max()), 0, 255).astype(np.uint8),
        (9, 6),
        flags=cv2.CALIB_CB_ACCURACY,
    )
    if not found:
        return None
    corners = corners.reshape(-1, 2)
    return corners if np.abs(corners - truth).max() < 3 else corners[::-1]


def test_corners_beat_opencv_and_reach_two_hundredths(views: list) -> None:
    ours, theirs = [], []
    for image, truth in views:
        corners = detect(image, PATTERN, bayer="GRBG")
        assert corners is not None
        peer = _opencv_corners(image, truth)
        if peer is not None:  # compared on the views both find
            ours.append(corners.pixels - truth)
            theirs.append(peer - truth)
    assert len(ours) >= 2
    rms = float(np.sqrt(np.mean(np.sum(np.concatenate(ours) ** 2, axis=1))))
    rms_cv = float(np.sqrt(np.mean(np.sum(np.concatenate(theirs) ** 2, axis=1))))
    assert rms <= 0.02
    assert rms <= 0.5 * rms_cv, f"ours {rms:.4f} px, findChessboardCornersSB {rms_cv:.4f} px"


def test_uncertainty_predicts_the_error(views: list) -> None:
    errors, sigmas = [], []
    for image, truth in views:
        corners = detect(image, PATTERN, bayer="GRBG")
        assert corners is not None
        errors.append(corners.pixels - truth)
        sigmas.append(corners.sigma_px)
    per_axis = float(np.sqrt(np.mean(np.concatenate(errors) ** 2)))
    predicted = float(np.sqrt(np.mean(np.concatenate(sigmas) ** 2)))
    assert 0.6 < per_axis / predicted < 1.6, (
        f"error {per_axis:.4f} px, predicted {predicted:.4f} px"
    )


def test_board_turned_half_round_keeps_its_corner_order() -> None:
    rig = make_rig(640, 480, cameras=1, seed=13, bayer=None)
    pose = board_poses(rig, BOARD, 1, seed=14)[0]
    centre = np.array([4 * 25.0, 2.5 * 25.0, 0.0])
    turn = rotation_matrix(np.array([0.0, 0.0, np.pi]))
    turned = BoardPose(pose.R @ turn, pose.t_mm + pose.R @ (centre - turn @ centre))
    image = render_view(rig, BOARD, turned, seed=1)[0]
    corners = detect(image, PATTERN)
    assert corners is not None
    assert np.abs(corners.pixels - corner_truth(rig, BOARD, turned)[0]).max() < 0.1


def test_views_without_the_board_or_another_board_give_none(views: list) -> None:
    image = views[0][0]
    assert detect(np.full_like(image, 800), PATTERN, bayer="GRBG") is None
    assert detect(image, Checkerboard(7, 4, 25.0), bayer="GRBG") is None
