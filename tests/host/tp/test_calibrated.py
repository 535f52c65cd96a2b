"""The tile processor on raw images of a calibrated quad (quad.json "calibration").

The simulator's calibration rig (`elphel_sim.calib_rig`) has cameras with their own
distortion, focal length, principal point and a rotation of about 0.4 degrees;
`elphel_sim.calib_scene` renders the quad's standard scene through them (raw images) and
through the same rig made ideal (rectified images), whose `tile_truth` is the true
disparity of every tile for both.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from elphel_host.calibrate.camera_model import CameraModel
from elphel_host.calibrate.residual_grid import ResidualGrid
from elphel_host.cli import main as elphel_main
from elphel_host.depth.products import dsi_depth
from elphel_host.errors import InputFormatError
from elphel_host.tp import capture, io
from elphel_host.tp.calibrated import CalibratedGeometry, copy_calibration, read_calibration
from elphel_host.tp.dsi import read_dsi
from elphel_host.tp.geometry import (
    IDEAL_POSITIONS,
    PAIRS,
    QuadGeometry,
    place_tiles,
    tile_centres,
    window_at,
)
from elphel_host.tp.images import QuadImages
from elphel_host.tp.layout import QuadLayout
from elphel_host.tp.processor import disparity_map
from elphel_sim.calib_rig import make_rig
from elphel_sim.calib_scene import (
    camera_centres_mm,
    rectified_rig,
    render_raw_quad,
    write_raw_quad_dir,
    write_true_calibration,
)
from elphel_sim.quad import TileTruth, render_quad, standard_scene, tile_truth, write_quad_dir

W, H = 640, 480


def rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(a))))


def ideal_cameras(baseline_mm: float, focal_px: float) -> list[tuple[CameraModel, np.ndarray]]:
    out = []
    for px, py in IDEAL_POSITIONS:
        lens = CameraModel(W, H, focal_px, focal_px, (W - 1) / 2, (H - 1) / 2)
        centre = baseline_mm * np.array([px + 0.5, py + 0.5, 0.0])  # camera 0's frame
        out.append((lens, np.eye(3), -centre))
    return out


def test_an_ideal_calibration_places_tiles_as_the_ideal_square() -> None:
    cal = CalibratedGeometry.from_cameras(ideal_cameras(150.0, 500.0))
    assert cal.baseline_mm == pytest.approx(150.0) and cal.focal_px == pytest.approx(500.0)
    geometry = QuadGeometry(calibration=cal)
    cy, cx = (c.ravel() for c in tile_centres(H // 8, W // 8))
    disparity = np.linspace(-1.0, 6.0, cx.size)
    for cam, position in enumerate(IDEAL_POSITIONS):
        got = geometry.place_camera(cam, cx, cy, disparity)
        want = place_tiles(cx, cy, disparity, position)
        assert np.array_equal(got.left_x, want.left_x) and np.array_equal(got.top_y, want.top_y)
        assert np.allclose(got.shift_x, want.shift_x, atol=1e-9)
        assert np.allclose(got.shift_y, want.shift_y, atol=1e-9)
    assert np.allclose(geometry.disparity_gain(cx, cy), 1.0, atol=1e-9)


def test_each_camera_sees_the_point_at_its_true_projection(tmp_path: Path) -> None:
    rig = make_rig(W, H, seed=3)
    cal = read_calibration(write_true_calibration(tmp_path, rig))
    rng = np.random.default_rng(0)
    x, y = rng.uniform(40, W - 40, 50), rng.uniform(40, H - 40, 50)
    depth_mm = rng.uniform(2e3, 2e4, 50)
    f = cal.focal_px
    # the virtual camera looks along camera 0's axis from the centre of the four cameras
    points = np.stack([(x - W / 2) / f * depth_mm, (y - H / 2) / f * depth_mm, depth_mm], -1)
    in_cam0 = points - camera_centres_mm(rig)[0]
    for cam, rc in enumerate(rig.cameras):
        want = rc.project(in_cam0) + 0.5  # OpenCV's pixel centres to continuous pixels
        got = cal.pixels(cam, x, y, f * cal.baseline_mm / depth_mm)
        assert np.allclose(np.stack(got, -1), want, atol=1e-6)


def test_compiled_placement_is_the_numpy_geometry_bit_for_bit(tmp_path: Path) -> None:
    # the tile processor places tiles through fused.lens_windows; pixels() is the NumPy
    # definition: the same operations in the same order give the same float64 values
    cal = read_calibration(write_true_calibration(tmp_path, make_rig(W, H, seed=5)))
    rng = np.random.default_rng(1)
    x, y = rng.uniform(-20, W + 20, 3000), rng.uniform(-20, H + 20, 3000)
    disparity = rng.uniform(-2.0, 40.0, 3000)
    for cam in range(4):
        px, py = cal.pixels(cam, x, y, disparity)
        got = cal.place(cam, x, y, disparity)
        for first, shift, want in ((got.left_x, got.shift_x, px), (got.top_y, got.shift_y, py)):
            want_first, want_shift = window_at(want)
            assert np.array_equal(first, want_first) and np.array_equal(shift, want_shift)
    # and the gain from the compiled pixels equals the one from the NumPy pixels
    gain = QuadGeometry(calibration=cal).disparity_gain(x.reshape(50, 60), y.reshape(50, 60))
    vectors = QuadGeometry().pair_vectors()
    one = np.ones_like(x)
    moved = [
        np.stack(cal.pixels(c, x, y, one), -1) - np.stack(cal.pixels(c, x, y, 0 * one), -1)
        for c in range(4)
    ]
    want = np.mean(
        [(moved[b] - moved[a]) @ v / (v @ v) for (a, b), v in zip(PAIRS, vectors, strict=True)],
        axis=0,
    )
    assert gain.shape == (50, 60)
    np.testing.assert_allclose(gain.ravel(), want, rtol=0, atol=1e-12)


def test_the_gain_is_the_lens_scale_where_tiles_are(tmp_path: Path) -> None:
    cal = read_calibration(write_true_calibration(tmp_path, make_rig(W, H, seed=3)))
    gain = QuadGeometry(calibration=cal).disparity_gain(
        np.array([W / 2, 40.0]), np.array([H / 2, 40.0])
    )
    # barrel distortion: about the focal length ratio in the centre, less in a corner
    assert gain[0] == pytest.approx(1.0, abs=0.03)
    assert 0.5 < gain[1] < gain[0] - 0.1


@pytest.fixture(scope="module")
def scene_dirs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path, TileTruth]:
    """Raw quad with the true calibration, the same without it, and the rectified quad."""
    root = tmp_path_factory.mktemp("scene")
    rig = make_rig(W, H, seed=0)
    ideal = rectified_rig(rig)
    scene = standard_scene(ideal, seed=0)
    raw = render_raw_quad(scene, rig, seed=1)
    cal = write_true_calibration(root / "calib", rig)
    calibrated = write_raw_quad_dir(root / "raw", raw, rig, calibration=cal.parent)
    plain = write_raw_quad_dir(root / "plain", raw, rig)
    rectified = write_quad_dir(root / "rect", render_quad(scene, seed=1), ideal)
    return calibrated, plain, rectified, tile_truth(scene)


def test_raw_images_with_their_calibration_are_as_good_as_rectified_ones(
    scene_dirs: tuple[Path, Path, Path, TileTruth],
) -> None:
    calibrated, plain, rectified, truth = scene_dirs
    scored = truth.interior & truth.textured
    errors = {}
    for name, root in (("calibrated", calibrated), ("plain", plain), ("rectified", rectified)):
        dsi = disparity_map(io.read_quad_dir(root).quad)
        errors[name] = rms((dsi["disparity"] - truth.disparity)[scored])
    assert errors["rectified"] < 0.04
    assert errors["calibrated"] <= 1.2 * errors["rectified"]
    assert errors["plain"] > 1.0  # the raw images read as ideal ones: visibly wrong


def test_a_plane_comes_out_at_its_distance(scene_dirs: tuple[Path, Path, Path, TileTruth]) -> None:
    calibrated, _, _, truth = scene_dirs
    qs = io.read_quad_dir(calibrated)
    cal = qs.quad.geometry.calibration
    assert isinstance(cal, CalibratedGeometry)
    dsi = disparity_map(qs.quad)
    depth = dsi_depth(dsi, qs.quad, cal.depth_optics()).depth_mm
    on_plane = truth.interior & (truth.label == truth.names.index("fronto_2.5"))
    true_mm = cal.focal_px * cal.baseline_mm / 2.5
    assert on_plane.sum() > 100
    assert abs(np.nanmedian(depth[on_plane]) / true_mm - 1) <= 0.005


def test_a_calibration_for_another_image_size_names_both_sizes(
    scene_dirs: tuple[Path, Path, Path, TileTruth], tmp_path: Path
) -> None:
    calibrated = scene_dirs[0]
    root = tmp_path / "quad"
    shutil.copytree(calibrated, root)
    write_true_calibration(root, make_rig(320, 240, seed=0))
    with pytest.raises(InputFormatError, match=r"320x240 images, the quad's images are 640x480"):
        io.read_quad_dir(root)
    with pytest.raises(InputFormatError, match=r"320x240 images, the quad's are 640x480"):
        copy_calibration(root, tmp_path, image_size=(W, H))


def test_images_of_another_size_than_the_calibration_are_refused(tmp_path: Path) -> None:
    cal = read_calibration(write_true_calibration(tmp_path, make_rig(W, H, seed=0)))
    images = np.zeros((4, 240, 320), dtype=np.float32)
    with pytest.raises(InputFormatError, match="calibration is for 640x480 images, the images"):
        QuadImages(images, geometry=QuadGeometry(calibration=cal))


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("../calib/calibration.json", "allowed: a path inside the directory"),
        ("/etc/calibration.json", "allowed: a path inside the directory"),
        ("missing.json", "no such calibration file"),
    ],
)
def test_the_calibration_must_be_a_file_inside_the_quad_directory(
    scene_dirs: tuple[Path, Path, Path, TileTruth], tmp_path: Path, name: str, message: str
) -> None:
    root = tmp_path / "quad"
    shutil.copytree(scene_dirs[0], root)
    doc = json.loads((root / "quad.json").read_text())
    doc["calibration"] = name
    (root / "quad.json").write_text(json.dumps(doc))
    with pytest.raises(InputFormatError, match=message):
        io.read_quad_dir(root)


def test_a_broken_calibration_is_named(tmp_path: Path) -> None:
    (tmp_path / "calibration.json").write_text('{"version": 1, "cameras": [{"fx": 1}]}')
    with pytest.raises(InputFormatError, match=r"not a readable calibration\.json"):
        read_calibration(tmp_path)
    (tmp_path / "calibration.json").write_text(json.dumps({"version": 1, "cameras": []}))
    with pytest.raises(InputFormatError, match="0 cameras; allowed: 4"):
        read_calibration(tmp_path)


def test_calibration_is_an_option_of_capture_only(
    scene_dirs: tuple[Path, Path, Path, TileTruth],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit) as stop:
        elphel_main(
            ["tp", str(scene_dirs[0]), "--out", str(tmp_path / "d.tif"), "--calibration", "c"]
        )
    assert stop.value.code == 2
    assert "--calibration: only with `elphel tp capture`" in capsys.readouterr().err


def test_tp_writes_a_metric_cloud_from_the_calibration(
    scene_dirs: tuple[Path, Path, Path, TileTruth],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    dsi, ply = tmp_path / "dsi.tif", tmp_path / "cloud.ply"
    code = elphel_main(["tp", str(scene_dirs[0]), "--out", str(dsi), "--ply", str(ply), "--json"])
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert result["depth"]["points"] > 1000 and ply.is_file()
    props = read_dsi(dsi)[1]
    assert props["calibration"] == "calibration.json"
    assert float(props["baselineMm"]) == pytest.approx(150.0, rel=1e-6)


def test_capture_copies_the_calibration_into_the_quad_directory(
    scene_dirs: tuple[Path, Path, Path, TileTruth], tmp_path: Path
) -> None:
    calibrated, plain, _, _ = scene_dirs
    manifest = io.QuadManifest.read(plain)
    frames = {p: SimpleNamespace(tiff=(plain / f"cam{p}.tif").read_bytes()) for p in range(4)}
    out = tmp_path / "captured"
    written = capture._write_set(out, manifest, frames, QuadLayout(), calibrated, (W, H), False)
    assert written.calibration == "calibration.json"
    assert json.loads((out / "quad.json").read_text())["calibration"] == "calibration.json"
    assert isinstance(io.read_quad_dir(out).quad.geometry.calibration, CalibratedGeometry)
    with pytest.raises(InputFormatError, match=r"640x480 images, the quad's are 320x240"):
        capture._write_set(
            tmp_path / "small", manifest, frames, QuadLayout(), out, (320, 240), False
        )
    assert not (tmp_path / "s").exists()


def test_capture_refuses_a_bad_calibration_before_touching_the_camera(tmp_path: Path) -> None:
    with pytest.raises(InputFormatError, match="no such calibration file"):
        capture.capture_quad(None, tmp_path / "q", calibration=tmp_path / "none")  # type: ignore[arg-type]


def test_lenses_with_residual_grids_are_placed_through_their_grids(tmp_path: Path) -> None:
    cal = read_calibration(write_true_calibration(tmp_path, make_rig(W, H, seed=5)))
    rng = np.random.default_rng(2)
    lenses = tuple(
        dataclasses.replace(lens, residual=ResidualGrid(W, H, rng.normal(0, 0.3, (7, 9, 2))))
        for lens in cal.lenses
    )
    gridded = dataclasses.replace(cal, lenses=lenses)
    x, y = rng.uniform(-20, W + 20, 3000), rng.uniform(-20, H + 20, 3000)
    disparity = rng.uniform(-2.0, 40.0, 3000)
    for cam in range(4):
        px, py = gridded.pixels(cam, x, y, disparity)
        plain = np.stack(cal.pixels(cam, x, y, disparity), -1)
        moved = np.stack([px, py], -1) - plain
        assert moved == pytest.approx(lenses[cam].residual.at(plain - 0.5), abs=1e-9)
        got = gridded.place(cam, x, y, disparity)
        for first, shift, want in ((got.left_x, got.shift_x, px), (got.top_y, got.shift_y, py)):
            assert np.allclose(first - shift, window_at(want)[0] - window_at(want)[1], atol=1e-9)
    gain = QuadGeometry(calibration=gridded).disparity_gain(x.reshape(50, 60), y.reshape(50, 60))
    plain_gain = QuadGeometry(calibration=cal).disparity_gain(x.reshape(50, 60), y.reshape(50, 60))
    assert np.abs(gain - plain_gain).max() > 1e-6  # the grid's slope changes the lens's scale
    assert np.abs(gain - plain_gain).max() < 0.05
