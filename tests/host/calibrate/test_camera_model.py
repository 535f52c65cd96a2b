"""The rational lens model against OpenCV's projectPoints, and the SPEC parser."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from elphel_host.calibrate.camera_model import CameraModel, rotation_matrix, rotation_vector
from elphel_host.calibrate.pattern import Checkerboard

LENS = CameraModel(
    640, 480, 505.0, 507.0, 321.0, 239.0, (-0.28, 0.09, 3e-4, -2e-4, -0.012, 0.05, 0.01, 0.002)
)


def test_projection_is_opencvs() -> None:
    rng = np.random.default_rng(0)
    points = rng.uniform([-300, -200, 500], [300, 200, 900], (200, 3))
    ours = LENS.project(points)
    theirs = cv2.projectPoints(
        points, np.zeros(3), np.zeros(3), LENS.camera_matrix, LENS.coefficients
    )[0]
    assert np.abs(ours - theirs.reshape(-1, 2)).max() < 1e-9


def test_rays_invert_the_projection() -> None:
    rng = np.random.default_rng(1)
    points = rng.uniform([-300, -200, 500], [300, 200, 900], (200, 3))
    rays = LENS.rays(LENS.project(points))
    assert np.abs(rays - points[:, :2] / points[:, 2:]).max() < 1e-10


def test_rotation_vectors_are_opencvs() -> None:
    rng = np.random.default_rng(2)
    for rvec in rng.normal(0, 0.8, (5, 3)):
        assert np.abs(rotation_matrix(rvec) - cv2.Rodrigues(rvec)[0]).max() < 1e-12
        assert np.abs(rotation_vector(rotation_matrix(rvec)) - rvec).max() < 1e-9


def test_model_round_trips_json() -> None:
    assert CameraModel.from_json(LENS.to_json()) == LENS


def test_spec_parses_and_names_the_form() -> None:
    board = Checkerboard.parse("checkerboard:9x6:25")
    assert (board.cols, board.rows, board.square_mm) == (9, 6, 25.0)
    assert board.object_points_mm()[10].tolist() == [25.0, 25.0, 0.0]
    with pytest.raises(ValueError, match="COLSxROWS"):
        Checkerboard.parse("chessboard:9x6")
    with pytest.raises(ValueError, match="must be odd"):
        Checkerboard.parse("checkerboard:8x6:20")
