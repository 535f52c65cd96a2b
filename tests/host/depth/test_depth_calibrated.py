"""`elphel depth` on a calibrated quad burst: raw, distorted frames and their calibration.

The simulator's calibration rig (`elphel_sim.calib_rig`: each camera with its own barrel
distortion, focal length, principal point and a rotation of about 0.4 degrees) records a
textured plane at a known distance from several carriage positions, as the quad on the
stage does; the burst's quad.json names the rig's true calibration.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from elphel_host.burst.io import read_quad_burst, write_quad_burst
from elphel_host.cli import main
from elphel_host.cloud.ply import read_ply
from elphel_host.depth.pipeline import DepthConfig, quad_burst_depth, read_and_run
from elphel_host.depth.raw_views import calibration_document, raw_view
from elphel_host.errors import InputFormatError
from elphel_host.mfsr.local_motion import ParallaxModel, fuse_parallax
from elphel_host.tp import io
from elphel_host.tp.calibrated import (
    CalibratedGeometry,
    copy_calibration,
    read_calibration,
    scaled,
    scaled_lens,
)
from elphel_sim.calib_rig import QUAD_POSITIONS, CalibRig, make_rig
from elphel_sim.calib_scene import (
    camera_centres_mm,
    raw_radiance,
    rectified_rig,
    write_true_calibration,
)
from elphel_sim.quad import QuadScene, fronto_rect
from elphel_sim.render import expose, mosaic

W, H = 192, 144
PLANE_DISPARITY_PX = 2.5
POSITIONS_MM = [31.0 * k for k in range(16)]  # as `elphel burst plan --scale 2 --bayer`
AXIS_DEG = 14.0


@pytest.fixture(scope="module")
def rig() -> CalibRig:
    return make_rig(W, H, seed=0)


@pytest.fixture(scope="module")
def cal(rig: CalibRig, tmp_path_factory: pytest.TempPathFactory) -> CalibratedGeometry:
    return read_calibration(write_true_calibration(tmp_path_factory.mktemp("cal"), rig))


def test_the_up_sampled_calibration_sees_every_point_at_scale_times_its_pixel(
    cal: CalibratedGeometry,
) -> None:
    rng = np.random.default_rng(0)
    x, y = rng.uniform(10, W - 10, 200), rng.uniform(10, H - 10, 200)
    d = rng.uniform(-0.5, 6.0, 200)
    for s in (1, 2, 3):
        up = scaled(cal, s)
        assert up.image_size == (W * s, H * s)
        for cam in range(4):
            lr = np.stack(cal.pixels(cam, x, y, d), -1)
            sr = np.stack(up.pixels(cam, s * x, s * y, s * d), -1)
            assert np.allclose(sr, s * lr, atol=1e-9)
        # depth Z = f B / D is the same on both grids
        assert up.depth_optics().depth_mm(s * d[d > 0]) == pytest.approx(
            cal.depth_optics().depth_mm(d[d > 0])
        )
    with pytest.raises(ValueError, match=r"scale=1\.5; allowed: an integer >= 1"):
        scaled_lens(cal.lenses[0], 1.5)  # type: ignore[arg-type]


def test_the_up_sampled_lens_matches_the_fusion_s_output_grid(cal: CalibratedGeometry) -> None:
    """A point's value on MFSR's output, looked up with the scaled lens, is its LR value."""
    lens = cal.lenses[1]
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    # smooth, not linear in x or y: a wrong half-pixel offset shows up
    image = (1000 + 3 * xs + 2 * ys + 20 * np.sin(xs / 9) * np.cos(ys / 7)).astype(np.float32)
    s = 2
    fused, _ = fuse_parallax(
        [image, image],
        ParallaxModel(((0.0, 0.0),) * 2),
        np.zeros((H, W), np.float32),
        scale=s,
        bayer=None,
    )
    rng = np.random.default_rng(1)
    rays = np.column_stack([rng.uniform(-0.3, 0.3, (4000, 2)), np.ones(4000)])
    at_lr = lens.project(rays)  # (0, 0) at the centre of the first pixel: array indices
    at_sr = scaled_lens(lens, s).project(rays)
    want = ndimage.map_coordinates(image, [at_lr[:, 1], at_lr[:, 0]], order=1)

    def bias(dx: float) -> float:
        """Mean difference of the fused image at the scaled lens's pixels, moved by dx."""
        got = ndimage.map_coordinates(fused, [at_sr[:, 1], at_sr[:, 0] + dx], order=1)
        return float(np.mean(got - want))

    # one frame fills each LR pixel's S x S output pixels alike (within +-1/4 LR px of
    # its centre, zero on average); half a fused pixel off is 1/4 LR px, 0.75 DN here
    assert abs(bias(0.0)) < 0.1
    assert abs(bias(0.5)) > 0.5 and abs(bias(-0.5)) > 0.5


def test_the_calibration_document_keeps_the_geometry(
    cal: CalibratedGeometry, tmp_path: Path
) -> None:
    up = scaled(cal, 2)
    (tmp_path / "calibration.json").write_text(json.dumps(calibration_document(up)))
    back = read_calibration(tmp_path)
    rng = np.random.default_rng(2)
    x, y, d = rng.uniform(0, 2 * W, 50), rng.uniform(0, 2 * H, 50), rng.uniform(0, 8, 50)
    for cam in range(4):
        assert np.allclose(np.stack(back.pixels(cam, x, y, d)), np.stack(up.pixels(cam, x, y, d)))
    assert back.baseline_mm == pytest.approx(up.baseline_mm)


def test_a_raw_view_moves_its_pixels_as_the_carriage_does(cal: CalibratedGeometry) -> None:
    """``D_i(q) w_i |v|`` is how far the carriage moves camera i's raw pixel q."""
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64) + 0.5
    centre = (1.5 + xs / W + ys / H).astype(np.float32)  # a slanted surface
    u = (np.sin(np.radians(AXIS_DEG)), np.cos(np.radians(AXIS_DEG)))  # (dy, dx)
    virtual = ParallaxModel(((0.0, 0.0), (0.2 * u[0], 0.2 * u[1])))
    for cam in range(4):
        view = raw_view(centre, cal, cam, direction=u)
        (_, _), (vy, vx) = view.model(virtual, u).per_disparity
        # forward: virtual pixels p with their disparity, where camera cam sees them,
        # before and after the carriage moved (the virtual image moves by -D v)
        sl = np.s_[20:-20:7, 20:-20:7]
        px, py, d = xs[sl], ys[sl], centre[sl].astype(np.float64)
        qx, qy = cal.pixels(cam, px, py, d)
        mx, my = cal.pixels(cam, px - 0.2 * d * u[1], py - 0.2 * d * u[0], d)
        dq = ndimage.map_coordinates(view.disparity, [qy - 0.5, qx - 0.5], order=1)
        err = np.hypot(qx - dq * vx - mx, qy - dq * vy - my) / np.hypot(mx - qx, my - qy)
        # the camera's roll and the lens's scale are taken in: near the centre the model
        # holds within 2 % (one direction serves the whole image); the strong barrel
        # lens's shear across the motion (radial and tangential scales apart by about
        # 2 k1 r^2, k1 = -0.28) is left out: up to 11 % in a corner
        near = np.hypot(px - W / 2, py - H / 2) < 0.1 * cal.focal_px
        assert near.any() and np.max(err[near]) < 0.02
        assert np.median(err) < 0.03 and np.max(err) < 0.12
        assert np.ptp(view.gain) > 0.2  # the lens's scale does vary over the image


def render_calibrated_burst(root: Path, rig: CalibRig, calibration: Path) -> float:
    """A quad burst of the raw cameras before a plane; its true distance (mm)."""
    ideal = rectified_rig(rig)
    scene = QuadScene(
        ideal, [fronto_rect(ideal, "plane", PLANE_DISPARITY_PX, (-0.4, -0.4, 1.4, 1.4), seed=5)]
    )
    t = np.radians(AXIS_DEG)
    rng = np.random.default_rng(7)
    frames = []
    for s in POSITIONS_MM:
        centres = camera_centres_mm(rig) + np.array([s * np.cos(t), s * np.sin(t), 0.0])
        frames.append(
            [
                expose(
                    mosaic(raw_radiance(scene, cam, origin), rig.bayer),
                    exposure_us=rig.exposure_us,
                    model=rig.sensor,
                    rng=rng,
                )
                for cam, origin in zip(rig.cameras, centres, strict=True)
            ]
        )
    infos = [
        {"stage_mm": s, "caliper_mm": s, "timestamp_ns": 10_000_000 * k}
        for k, s in enumerate(POSITIONS_MM)
    ]
    write_quad_burst(
        root,
        np.stack(frames, axis=1),
        positions=QUAD_POSITIONS,
        infos=infos,
        bayer=rig.bayer,
        stage={"axis_angle_deg": AXIS_DEG},
        full_scale_dn=float((1 << rig.sensor.bits) - 1),
    )
    name = copy_calibration(calibration, root, image_size=rig.size)
    doc = json.loads((root / "quad.json").read_text())
    (root / "quad.json").write_text(json.dumps({**doc, "calibration": name}))
    return ideal.depth_mm(PLANE_DISPARITY_PX)


@pytest.fixture(scope="module")
def burst(rig: CalibRig, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, float]:
    root = tmp_path_factory.mktemp("qbcal")
    calibration = write_true_calibration(root / "calib", rig)
    return root / "qb", render_calibrated_burst(root / "qb", rig, calibration)


@pytest.mark.slow  # renders 64 raw frames (once for the module)
def test_a_plane_comes_out_at_its_distance_from_a_calibrated_burst(
    burst: tuple[Path, float], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    qb, true_mm = burst
    out = tmp_path / "out"
    assert main(["depth", str(qb), "--scale", "2", "--out", str(out), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["cameras"]["cam0"]["parallax_from"] == "caliper"
    z = read_ply(r["ply"]).xyz[:, 2].astype(np.float64)
    assert len(z) > 0.5 * r["tiles"]
    assert abs(np.median(z) / true_mm - 1) <= 0.005
    assert np.percentile(np.abs(z / true_mm - 1), 90) <= 0.03
    # the fused quad carries the up-sampled calibration: `elphel tp` reads it as it is
    fused = io.read_quad_dir(out / "fused")
    got = fused.quad.geometry.calibration
    assert isinstance(got, CalibratedGeometry) and got.image_size == (2 * W, 2 * H)


@pytest.mark.slow  # renders 64 raw frames (once for the module)
def test_without_its_calibration_the_raw_burst_is_visibly_wrong(
    burst: tuple[Path, float], tmp_path: Path
) -> None:
    qb, true_mm = burst
    plain = tmp_path / "qb"
    shutil.copytree(qb, plain)
    doc = json.loads((plain / "quad.json").read_text())
    del doc["calibration"]
    cal = read_calibration(qb / "calibration.json")
    doc["optics"] = {
        "focal_length_mm": cal.focal_px * 1e-3,
        "pixel_pitch_um": 1.0,
        "baseline_mm": cal.baseline_mm,
    }
    (plain / "quad.json").write_text(json.dumps(doc))
    run, _ = read_and_run(plain, config=DepthConfig(scale=2))
    z = run.depth.cloud.xyz[:, 2].astype(np.float64)
    assert len(z) == 0 or np.median(np.abs(z / true_mm - 1)) > 0.1


@pytest.mark.slow  # renders 64 raw frames (once for the module)
def test_a_named_calibration_is_not_ignored(burst: tuple[Path, float]) -> None:
    qb = read_quad_burst(burst[0])
    with pytest.raises(InputFormatError, match=r"names calibration='calibration\.json', none"):
        quad_burst_depth(qb)


@pytest.mark.slow  # renders 64 raw frames (once for the module)
def test_without_stage_positions_the_frames_registration_gives_the_motion(
    burst: tuple[Path, float], tmp_path: Path
) -> None:
    qb, true_mm = burst
    bare = tmp_path / "qb"
    shutil.copytree(qb, bare)
    for cam in range(4):
        manifest = bare / f"cam{cam}" / "manifest.json"
        doc = json.loads(manifest.read_text())
        for frame in doc["frames"]:
            del frame["stage_mm"], frame["caliper_mm"]
        manifest.write_text(json.dumps(doc))
    run, _ = read_and_run(bare, config=DepthConfig(scale=2))
    assert run.info["cam2"]["parallax_from"] == "registration"
    z = run.depth.cloud.xyz[:, 2].astype(np.float64)
    assert abs(np.median(z) / true_mm - 1) <= 0.005
