"""DSI -> depth and point cloud: exact on a synthetic DSI, close to the truth on a quad."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from elphel_host.cli import main
from elphel_host.cloud.ply import read_ply
from elphel_host.depth.geometry import DepthOptics
from elphel_host.depth.products import dsi_depth, read_depth_tiff
from elphel_host.errors import InputFormatError
from elphel_host.tp import io
from elphel_host.tp.images import QuadImages
from elphel_sim import quad as simquad

RIG = simquad.QuadRig(width=384, height=288)
OPTICS = DepthOptics(RIG.focal_length_mm, RIG.pixel_pitch_um, RIG.baseline_mm)


def test_optics_agree_with_the_simulator() -> None:
    for d in (0.37, 2.5, 5.2):
        assert OPTICS.depth_mm(np.array(d)) == pytest.approx(RIG.depth_mm(d), rel=1e-12)
    z = 123456.0
    p = OPTICS.points_mm(np.array(100.5), np.array(7.25), np.array(z), image_size=(384, 288))
    assert np.allclose(p, RIG.point_mm(100.5, 7.25, z), rtol=1e-12)
    # up-sampling by 2: twice the disparity, same depth
    assert OPTICS.scaled(2).depth_mm(np.array(5.0)) == pytest.approx(OPTICS.depth_mm(np.array(2.5)))
    assert np.isnan(OPTICS.depth_mm(np.array([0.0, -1.0]))).all()


def test_optics_from_quad_json() -> None:
    with pytest.raises(InputFormatError, match="optics lacks pixel_pitch_um, baseline_mm"):
        DepthOptics.from_optics({"focal_length_mm": 4.5}, source="q/quad.json")
    with pytest.raises(InputFormatError, match="optics lacks focal_length_mm"):
        DepthOptics.from_optics(None, source="q/quad.json")
    with pytest.raises(InputFormatError, match=r"baseline_mm=-1.0; allowed: a number > 0"):
        DepthOptics(4.5, 2.2, -1.0)


def test_synthetic_dsi_counts_and_points() -> None:
    ty, tx = 36, 48
    disparity = np.full((ty, tx), 2.0, np.float32)
    strength = np.full((ty, tx), 0.5, np.float32)
    disparity[0, :10] = 0.0  # at infinity
    disparity[1, :3] = np.nan
    strength[5, :7] = 0.05  # weak
    quad = QuadImages(np.full((4, 288, 384), 0.25, np.float32), bayer="GRBG")
    r = dsi_depth({"disparity": disparity, "strength": strength}, quad, OPTICS, min_strength=0.1)
    assert (r.tiles, r.infinite, r.weak, len(r.cloud)) == (ty * tx, 13, 7, ty * tx - 20)
    assert np.isnan(r.depth_mm[0, :10]).all() and np.isnan(r.depth_mm[5, :7]).all()
    z = RIG.depth_mm(2.0)
    assert np.allclose(r.cloud.xyz[:, 2], z, rtol=1e-6)
    # the last tile's point is where the simulator puts its centre pixel
    assert np.allclose(r.cloud.xyz[-1], RIG.point_mm(8 * 47 + 4, 8 * 35 + 4, z), rtol=1e-6)
    assert r.cloud.rgb is not None and np.ptp(r.cloud.rgb) == 0  # uniform grey image
    with pytest.raises(InputFormatError, match="no 'strength' layer"):
        dsi_depth({"disparity": disparity}, quad, OPTICS)
    with pytest.raises(InputFormatError, match="DSI has 3x2 tiles, the quad 48x36"):
        dsi_depth({"disparity": disparity[:2, :3], "strength": strength[:2, :3]}, quad, OPTICS)


@pytest.fixture(scope="module")
def simulated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, simquad.TileTruth]:
    return simquad.simulate_quad_dir(tmp_path_factory.mktemp("q") / "quad", RIG, seed=1)


def test_tp_ply_on_a_simulated_quad(
    simulated: tuple[Path, simquad.TileTruth], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root, truth = simulated
    ply = tmp_path / "cloud.ply"
    code = main(["tp", str(root), "--out", str(tmp_path / "dsi.tif"), "--ply", str(ply), "--json"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)["depth"]
    cloud = read_ply(ply)
    assert out["points"] == len(cloud) and out["tiles"] == 48 * 36
    assert out["points"] + out["weak_tiles"] + out["infinite_tiles"] == out["tiles"]
    depth, meta = read_depth_tiff(out["depth_tiff"])
    assert depth.shape == (36, 48) and meta["unit"] == "mm" and meta["min_strength"] == 0.15
    # the texture-less rectangle is left out (weak), the near planes are measured
    flat = truth.label == truth.names.index("flat")
    assert np.isnan(depth[flat & truth.interior]).mean() > 0.9
    for name in ("fronto_2.5", "fronto_5.2"):
        sel = (truth.label == truth.names.index(name)) & truth.interior
        true_z = RIG.depth_mm(float(truth.disparity[sel][0]))
        rel = np.abs(depth[sel] / true_z - 1)
        assert np.isfinite(rel).mean() > 0.95
        assert np.nanmedian(rel) < 0.01, name  # 0.03 px of 2.5 px is 1.2 % RMS
    for key in ("cloud_png", "depth_png"):
        with Image.open(out[key]) as im:
            assert im.format == "PNG"


def test_tp_ply_needs_optics(
    simulated: tuple[Path, simquad.TileTruth], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root, _ = simulated
    m = io.QuadManifest.read(root)
    bare = io.QuadManifest(cameras=m.cameras, bayer=m.bayer, full_scale_dn=m.full_scale_dn)
    q2 = tmp_path / "q2"
    q2.mkdir()
    for cam in m.cameras:
        (q2 / cam.file).write_bytes((root / cam.file).read_bytes())
    bare.write(q2)
    code = main(["tp", str(q2), "--out", str(tmp_path / "d.tif"), "--ply", str(tmp_path / "c.ply")])
    assert code == 1
    assert "optics lacks focal_length_mm" in capsys.readouterr().err
    assert not (tmp_path / "d.tif").exists()
