"""What the guided capture judges: a board's tilt and size, coverage, hints."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from elphel_host.calibrate.camera_model import rotation_matrix
from elphel_host.calibrate.guide import (
    CaptureLimits,
    Placement,
    coverage,
    empty_regions,
    hints,
    missing_tilts,
    placement,
    text_map,
    unlinked,
)
from elphel_host.calibrate.pattern import Checkerboard

PATTERN = Checkerboard(9, 6, 25.0)
SIZE = (640, 480)


def _corners(rvec_deg: tuple[float, float, float], t_mm: tuple[float, float, float]) -> np.ndarray:
    """The board's corners seen by a pinhole of focal length the image width, board centred."""
    obj = PATTERN.object_points_mm() - np.array([100.0, 62.5, 0.0])
    r = rotation_matrix(np.radians(np.asarray(rvec_deg)))
    k = np.array([[640.0, 0, 319.5], [0, 640.0, 239.5], [0, 0, 1]])
    pixels, _ = cv2.projectPoints(obj, cv2.Rodrigues(r)[0], np.asarray(t_mm, float), k, None)
    return np.asarray(pixels).reshape(-1, 2)


@pytest.mark.parametrize(
    ("rvec_deg", "turn_deg", "tilt_deg"),
    [
        ((0.0, 30.0, 0.0), -30.0, 0.0),  # about the vertical axis, right edge nearer
        ((0.0, -25.0, 0.0), 25.0, 0.0),
        ((30.0, 0.0, 0.0), 0.0, 30.0),  # about the horizontal axis, bottom edge farther
        ((-20.0, 0.0, 0.0), 0.0, -20.0),
    ],
)
def test_the_tilt_is_read_from_the_corners(
    rvec_deg: tuple[float, float, float], turn_deg: float, tilt_deg: float
) -> None:
    where = placement(_corners(rvec_deg, (0.0, 0.0, 600.0)), PATTERN, SIZE)
    assert where.turn_deg == pytest.approx(turn_deg, abs=0.5)
    assert where.tilt_deg == pytest.approx(tilt_deg, abs=0.5)
    assert where.centre == pytest.approx((0.5, 0.5), abs=0.05)


def test_area_and_distance_follow_the_board() -> None:
    near = placement(_corners((0, 0, 0), (0, 0, 600)), PATTERN, SIZE)
    far = placement(_corners((0, 0, 0), (0, 0, 1200)), PATTERN, SIZE)
    # 200 x 125 mm at 600 mm through f = 640 px: 213 x 133 px of 640 x 480
    assert near.area_percent == pytest.approx(100 * 213.3 * 133.3 / (640 * 480), rel=0.01)
    assert far.area_percent == pytest.approx(near.area_percent / 4, rel=0.01)
    assert near.distance(far) > 1 and near.distance(near) == 0
    turned = placement(_corners((0, 20, 0), (0, 0, 600)), PATTERN, SIZE)
    assert near.distance(turned) > 1


def test_coverage_counts_the_cells_a_board_covers() -> None:
    corners = _corners((0, 0, 0), (0, 0, 600))
    count = coverage([corners, corners], SIZE)
    assert count.shape == (12, 16) and count.max() == 2
    # the board spans x 213..426 px, y 173..306 px: cells 5..10 by 4..7
    assert count[5, 7] == 2 and count[6, 8] == 2
    assert count[0].sum() == 0 and count[:, 0].sum() == 0 and count[11].sum() == 0
    assert empty_regions(count) == [
        "top-left",
        "top",
        "top-right",
        "left",
        "right",
        "bottom-left",
        "bottom",
        "bottom-right",
    ]
    assert empty_regions(np.ones((12, 16), dtype=np.int64)) == []


def test_tilts_with_too_few_views_are_named() -> None:
    def at(turn: float, tilt: float) -> Placement:
        return Placement((0.5, 0.5), 10.0, turn, tilt)

    views = [at(-20, 0), at(-30, 5), at(25, 0), at(0, 20), at(0, 30), at(0, -16), at(0, -40)]
    assert missing_tilts(views) == ["right edge farther"]
    assert missing_tilts([*views, at(18, 0)]) == []


def test_cameras_not_linked_to_camera_0_are_named() -> None:
    assert unlinked(4, [[0, 1], [1, 3], [2]]) == [2]
    assert unlinked(4, [[0, 1], [1, 3], [2, 3]]) == []
    full = np.ones((12, 16), dtype=np.int64)
    said = hints([full] * 4, [], [[0, 1], [2, 3]])
    assert any("cam2, cam3 share no view with cam0" in h for h in said)
    assert any("left edge farther" in h for h in said)
    assert not any("put the board" in h for h in said)


def test_the_text_map_marks_each_cell() -> None:
    count = np.zeros((12, 16), dtype=np.int64)
    count[0, :4] = [0, 1, 2, 7]
    lines = text_map(count, "cam0")
    assert len(lines) == 13 and all(len(line) == 32 for line in lines)
    assert lines[1].startswith("..--++##..")


def test_limits_name_what_is_allowed() -> None:
    with pytest.raises(ValueError, match="max_blur_px=0; allowed: > 0"):
        CaptureLimits(max_blur_px=0)
    with pytest.raises(ValueError, match="allowed: 0 < x < 100"):
        CaptureLimits(min_area_percent=100)
