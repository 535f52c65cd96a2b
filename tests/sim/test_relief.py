"""The relief scene and its truth: ray-cast depth agrees with the rendered images and the rig."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
import tifffile

from elphel_host.cloud.ply import read_ply
from elphel_host.tp.images import QuadImages
from elphel_host.tp.processor import disparity_map
from elphel_sim import relief
from elphel_sim.quad import QuadRig
from elphel_sim.scenarios import QUAD_RIG_AXIS_DEG, build

pytestmark = pytest.mark.slow  # renders the relief scene

RIG = QuadRig(width=320, height=240)


@pytest.fixture(scope="module")
def scene() -> relief.QuadScene:
    return relief.relief_scene(RIG, seed=2)


def test_cylinder_is_smooth_and_where_asked(scene: relief.QuadScene) -> None:
    spec = relief.ReliefSpec()
    facets = [r for r in scene.regions if r.name.startswith("cylinder_")]
    assert len(facets) == relief.CYLINDER_FACETS
    z_front = RIG.depth_mm(spec.cylinder_front)
    r = spec.cylinder_radius_mm
    axis_z = z_front + r
    half = np.radians(150 / relief.CYLINDER_FACETS / 2)
    sagitta = r * (1 - np.cos(half))
    # every chord's midpoint is inside the circle by exactly the sagitta
    axis_x = np.mean([float(f.plane.origin[0]) for f in facets])
    for f in facets:
        dist = np.hypot(f.plane.origin[0] - axis_x, f.plane.origin[2] - axis_z)
        assert dist == pytest.approx(r - sagitta, abs=1e-6)
    nearest = min(float(f.plane.origin[2]) for f in facets)
    assert z_front < nearest < z_front + 2 * sagitta
    assert sagitta < 25.0  # mm at ~88 m: far below the depth resolution


def test_depth_maps_and_reference_cloud(scene: relief.QuadScene, tmp_path: Path) -> None:
    files = relief.write_truth(tmp_path, scene, step_px=2.0)
    ref = read_ply(files["reference"])
    z = ref.xyz[:, 2]
    spec = relief.ReliefSpec()
    assert z.max() == pytest.approx(RIG.depth_mm(spec.wall), rel=1e-5)
    assert z.min() == pytest.approx(RIG.depth_mm(spec.steps[2]), rel=1e-5)
    # every depth map sees the wall and the near step, camera 1 (right) sees them shifted left
    d0 = tifffile.imread(files["depth_cam0"])
    d1 = tifffile.imread(files["depth_cam1"])
    assert d0.shape == (240, 320) and np.isfinite(d0).all()
    near = RIG.depth_mm(spec.steps[2])
    cols0 = np.nonzero(np.isclose(d0[60], near, rtol=1e-5))[0]
    cols1 = np.nonzero(np.isclose(d1[60], near, rtol=1e-5))[0]
    # camera 1 is one side to the right: the step appears D px further left
    assert cols0.min() - cols1.min() == pytest.approx(spec.steps[2], abs=1.0)


def test_rendered_quad_matches_the_truth(scene: relief.QuadScene) -> None:
    images = relief.render_quad_at(scene, seed=3).astype(np.float32) / 4095
    dsi = disparity_map(QuadImages(images, bayer=RIG.bayer))
    ty, tx = dsi["disparity"].shape
    yy, xx = np.meshgrid(8.0 * np.arange(ty) + 4, 8.0 * np.arange(tx) + 4, indexing="ij")
    depth, label = relief.cast(scene, xx, yy)
    interior = np.ones(label.shape, bool)
    for dx, dy in (
        (-14, 0),
        (14, 0),
        (0, -14),
        (0, 14),
        (-10, -10),
        (10, 10),
        (-10, 10),
        (10, -10),
    ):
        interior &= relief.cast(scene, xx + dx, yy + dy)[1] == label
    names = [r.name for r in scene.regions]
    medians = []
    for name in ("wall", "step_0", "step_1", "step_2"):
        sel = (label == names.index(name)) & interior
        assert sel.sum() >= 5, name
        err = dsi["disparity"][sel] - RIG.disparity_px(depth[sel])
        # measured 320x240 seed 3: wall -0.001 px median (0.035 RMS), steps -0.04 .. 0.07
        assert abs(np.median(err)) < (0.01 if name == "wall" else 0.1), name
        medians.append(float(np.median(dsi["disparity"][sel])))
    assert medians == sorted(medians)


def test_quad_rig_scenario_moves_the_quad_with_the_carriage() -> None:
    sc = build("quad-rig", seed=0)
    assert sc.quad is not None and len(sc.ports) == 4
    before = sc.world.camera_pose("cam3").position_mm.copy()
    sc.world.rig.carriage_mm = 10.0
    moved = sc.world.camera_pose("cam3").position_mm - before
    t = np.radians(QUAD_RIG_AXIS_DEG)
    assert np.allclose(moved, [10 * np.cos(t), 10 * np.sin(t), 0.0])
    assert np.tan(t) == pytest.approx(0.25)


def test_inspection_endpoint_serves_the_truth(request: pytest.FixtureRequest) -> None:
    from fastapi.testclient import TestClient

    from elphel_host.cloud.ply import read_ply
    from elphel_sim.board import SimCameraBoard
    from elphel_sim.launcher import create_sim_app

    board = SimCameraBoard(build("quad-rig", seed=0), seed=0)
    request.addfinalizer(board.close)
    client = TestClient(create_sim_app(board))
    r = client.get("/quad/reference.ply", params={"step_px": 32})
    assert r.status_code == 200
    path = Path(tempfile.mkdtemp()) / "ref.ply"
    path.write_bytes(r.content)
    ref = read_ply(path)
    wall = RIG.depth_mm(relief.ReliefSpec().wall)
    assert len(ref) > 1000 and ref.xyz[:, 2].max() == pytest.approx(wall, rel=1e-5)
    # the carriage moves the quad by 1 m: the near step moves the other way in its frame
    moved = client.get("/quad/reference.ply", params={"step_px": 8, "carriage_mm": 1000})
    here = client.get("/quad/reference.ply", params={"step_px": 8, "carriage_mm": 0})
    near_z = RIG.depth_mm(relief.ReliefSpec().steps[2])
    xs = []
    for resp in (here, moved):
        path.write_bytes(resp.content)
        c = read_ply(path)
        xs.append(float(np.mean(c.xyz[np.isclose(c.xyz[:, 2], near_z, rtol=1e-5), 0])))
    t = np.radians(QUAD_RIG_AXIS_DEG)
    assert xs[1] - xs[0] == pytest.approx(-1000 * np.cos(t), abs=150)
    assert client.get("/quad/reference.ply", params={"step_px": 0.01}).status_code == 422
    d = client.get("/quad/depth/2")
    assert d.status_code == 200 and d.headers["content-type"] == "image/tiff"
    assert client.get("/quad/depth/4").status_code == 422


def test_small_quad_rig_puts_the_relief_in_a_centred_window() -> None:
    from elphel_camd.sensors import mt9p006

    sc = build("quad-rig-small", seed=0)
    assert sc.quad is not None and (sc.quad.rig.width, sc.quad.rig.height) == (640, 480)
    w = sc.quad.window
    assert w is not None and (w["WOI_WIDTH"], w["WOI_HEIGHT"]) == (640, 480)
    # the window's centre is on the optical axis of every camera
    for port in sc.ports:
        assert port.intrinsics.cx - mt9p006.CLEAR_LEFT == w["WOI_LEFT"] + 320
        assert port.intrinsics.cy - mt9p006.CLEAR_TOP == w["WOI_TOP"] + 240
    assert w["WOI_LEFT"] % 2 == 0 and w["WOI_TOP"] % 2 == 0
    # the same cameras and carriage as quad-rig; the relief's nearest step within the view
    big = build("quad-rig", seed=0)
    assert [p.intrinsics for p in sc.ports] == [p.intrinsics for p in big.ports]
    assert sc.world.rig.axis == big.world.rig.axis
    assert big.quad is not None and big.quad.window is None
    _, label = relief.cast(sc.quad, np.array([0.25 * 640]), np.array([0.25 * 480]))
    assert sc.quad.regions[label[0]].name.startswith("step_")
