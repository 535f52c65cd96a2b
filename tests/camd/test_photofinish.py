"""Photo-finish: strips of PF_HEIGHT rows at a fixed scan line, stacked into composites."""

import itertools

import numpy as np
import pytest

from elphel_camd.errors import ParameterRangeError
from elphel_camd.service import CameraService
from elphel_sim.board import SimCameraBoard
from elphel_sim.scenarios import LAB_LIGHT, PortSpec, Scenario, mt9p006_intrinsics
from elphel_sim.world import CameraMount, Plane, Rig, Scene, Texture, World

DEPTH_MM = 1000.0
SPEED_MM_S = 2000.0  # the object moves down (+y) through the scan line
HALF_HEIGHT_MM = 20.0
START_Y_MM = -600.0  # object centre at time 0: it crosses after the set-up frames
PF, STRIPS, WIDTH, LEFT, TOP = 2, 256, 256, 1168, 970


def world() -> World:
    dark = Plane(Texture(np.full((8, 8), 0.05), 100.0), origin=(0.0, 0.0, 2000.0))
    runner = Plane(
        Texture(np.full((8, 8), 0.9), 100.0),
        origin=(0.0, START_Y_MM, DEPTH_MM),
        half_extent_mm=(200.0, HALF_HEIGHT_MM),
        velocity_mm_s=(0.0, SPEED_MM_S, 0.0),
    )
    return World(Scene([dark, runner]), Rig(mounts={"cam0": CameraMount("cam0")}))


@pytest.fixture
def rig():
    intrinsics = mt9p006_intrinsics(4.5)
    scenario = Scenario(world(), [PortSpec("MT9P006", "cam0", intrinsics, LAB_LIGHT)])
    board = SimCameraBoard(scenario, noise=False)
    cam = CameraService(board)
    params = {
        "WOI_LEFT": LEFT,
        "WOI_TOP": TOP,
        "WOI_WIDTH": WIDTH,
        "PF_HEIGHT": PF,
        "WOI_HEIGHT": PF * STRIPS,
        "EXPOS": 60,
    }
    target = cam.set_params(0, params)
    while cam.capture(0)[0].frame < target:
        pass
    yield board, cam, intrinsics
    cam.close()


def test_composites_have_configured_shape_and_no_missing_strip(rig):
    board, cam, _intrinsics = rig
    frames = [cam.capture(0) for _ in range(3)]
    for frame, meta in frames:
        assert frame.image.shape == (PF * STRIPS, WIDTH)
        assert meta["PF_HEIGHT"] == PF and meta["WOI_HEIGHT"] == PF * STRIPS
        assert meta["pf_strips"] == STRIPS
    records = {r.frame: r for r in board.fpga[0].ring}
    rec = [records[f.frame] for f, _ in frames]
    assert [r.frame for r in rec] == [rec[0].frame, rec[0].frame + 1, rec[0].frame + 2]
    for a, b in itertools.pairwise(rec):
        # The next composite's first strip follows the previous one's last strip.
        assert b.start_s == pytest.approx(a.start_s + a.strips * a.strip_period_s, rel=1e-9)
    row_s = (WIDTH + 900) / 96e6
    assert rec[0].strip_period_s == pytest.approx(row_s * (PF + 9))


def test_object_appears_where_its_crossing_time_says(rig):
    board, cam, intrinsics = rig
    frames = [cam.capture(0) for _ in range(6)]
    strip_times, strip_means = [], []
    for frame, meta in frames:
        # Each strip's time as the metadata gives it to a user; checked against the truth.
        strips = meta["pf_strips"]
        times = (meta["timestamp_ns"] + meta["pf_strip_period_ns"] * np.arange(strips)) / 1e9
        means = frame.image.reshape(strips, PF, WIDTH).mean(axis=(1, 2))
        strip_times.extend(times)
        strip_means.extend(means)
    t = np.array(strip_times)
    bright = np.array(strip_means) > 0.5 * max(strip_means)
    assert np.all(np.diff(t) > 0)
    # The scan line's centre row, in array coordinates, seen at depth DEPTH_MM.
    row = 50 + TOP + PF / 2  # CLEAR_TOP + WOI_TOP + half a strip
    y_line = (row - intrinsics.principal_point[1]) * 2.2e-3 * DEPTH_MM / 4.5
    t_enter = (y_line - (START_Y_MM + HALF_HEIGHT_MM)) / SPEED_MM_S
    t_leave = (y_line - (START_Y_MM - HALF_HEIGHT_MM)) / SPEED_MM_S
    assert t[0] < t_enter and t_leave < t[-1], "the crossing must fall inside the captured strips"
    seen = t[bright]
    period = board.fpga[0].ring[-1].strip_period_s
    assert seen.min() == pytest.approx(t_enter, abs=1.5 * period)
    assert seen.max() == pytest.approx(t_leave, abs=1.5 * period)
    # Contiguous: every strip between entering and leaving shows the object.
    inside = (t >= seen.min()) & (t <= seen.max())
    assert bright[inside].all()


def test_photofinish_limits():
    scenario = Scenario(world(), [PortSpec("MT9P006", "cam0", mt9p006_intrinsics(4.5))])
    cam = CameraService(SimCameraBoard(scenario))
    try:
        with pytest.raises(ParameterRangeError, match="multiple of PF_HEIGHT"):
            cam.set_params(0, {"PF_HEIGHT": 4, "WOI_HEIGHT": 1002})
        with pytest.raises(ParameterRangeError, match="16384"):
            cam.set_params(0, {"PF_HEIGHT": 2, "WOI_HEIGHT": 16386})
        assert cam.set_params(0, {"PF_HEIGHT": 2, "WOI_HEIGHT": 16384, "WOI_TOP": 900}) > 0
    finally:
        cam.close()
