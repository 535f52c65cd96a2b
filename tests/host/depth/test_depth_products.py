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
from elphel_host.depth.products import (
    FAR_DISPARITY_PX,
    disagreeing,
    dsi_depth,
    left_out_swatches,
    read_depth_tiff,
)
from elphel_host.errors import InputFormatError
from elphel_host.preview import FAR_RGB, NO_VALUE_RGB
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


def test_tiles_whose_directions_disagree_are_left_out() -> None:
    ty, tx = 36, 48
    quad = QuadImages(np.full((4, 288, 384), 0.25, np.float32), bayer="GRBG")
    dsi = {k: np.full((ty, tx), 2.0, np.float32) for k in ("disparity", "disparity_hor")}
    dsi |= {k: np.full((ty, tx), 2.0, np.float32) for k in ("disparity_vert", "disparity_diag")}
    dsi |= {k: np.full((ty, tx), 0.5, np.float32) for k in ("strength", "strength_hor")}
    dsi |= {k: np.full((ty, tx), 0.5, np.float32) for k in ("strength_vert", "strength_diag")}
    # the demo's worst tile: combined 0.03 px (kilometres away), directions 6.58 / 0.17 / 2.39
    dsi["disparity"][3, 4] = 0.03
    for name, d in zip(("hor", "vert", "diag"), (6.58, 0.17, 2.39), strict=True):
        dsi["disparity_" + name][3, 4] = d
    # 2.0 against a median of 2.6: 23 % of the larger, kept; 2.0 against 2.7 (26 %): out
    dsi["disparity_hor"][5, 5], dsi["disparity_vert"][5, 5] = 2.6, 2.6
    dsi["disparity_hor"][6, 6], dsi["disparity_vert"][6, 6] = 2.7, 2.7
    # far: 0.05 against 0.25 is 80 % but within the 0.25 px floor; 0.05 against 0.31 is not
    dsi["disparity"][7, :2] = 0.05
    dsi["disparity_hor"][7, :2] = dsi["disparity_vert"][7, :2] = [0.25, 0.31]
    # a far-off direction that is weak does not count
    dsi["disparity_diag"][8, 8], dsi["strength_diag"][8, 8] = 9.0, 0.05
    # no confident direction: nothing to disagree with
    dsi["disparity_hor"][9, 9] = dsi["disparity_vert"][9, 9] = 9.0
    for name in ("hor", "vert", "diag"):
        dsi["strength_" + name][9, 9] = 0.01
    bad = disagreeing(dsi, min_strength=0.15, max_disagreement=0.25)
    assert sorted(zip(*np.nonzero(bad), strict=True)) == [(3, 4), (6, 6), (7, 1)]
    r = dsi_depth(dsi, quad, OPTICS, min_strength=0.15)
    assert (r.inconsistent, len(r.cloud), r.max_disagreement) == (3, ty * tx - 3, 0.25)
    assert np.isnan(r.depth_mm[3, 4]) and np.isfinite(r.depth_mm[5, 5])
    assert r.summary()["inconsistent_tiles"] == 3
    # off, or a DSI without the direction layers: every tile stays
    assert dsi_depth(dsi, quad, OPTICS, max_disagreement=None).inconsistent == 0
    two = {k: dsi[k] for k in ("disparity", "strength")}
    assert dsi_depth(two, quad, OPTICS).inconsistent == 0
    with pytest.raises(InputFormatError, match=r"max_disagreement=0\.0; allowed: > 0 or None"):
        dsi_depth(dsi, quad, OPTICS, max_disagreement=0.0)


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
    left_out = out["weak_tiles"] + out["infinite_tiles"] + out["inconsistent_tiles"]
    assert out["points"] + left_out == out["tiles"]
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
    check_depth_png(Path(out["depth_png"]), truth)
    check_disparity_png(tmp_path / "dsi.png", truth)


def _tile_colours(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """The colour at each tile's centre in a map picture (title line, 10-px margin)."""
    with Image.open(path) as im:
        picture = np.asarray(im.convert("RGB"))
    cell = int(np.ceil(400 / min(shape)))
    rows = 24 + np.arange(shape[0]) * cell + cell // 2
    cols = 10 + np.arange(shape[1]) * cell + cell // 2
    return picture[np.ix_(rows, cols)]


def check_depth_png(path: Path, truth: simquad.TileTruth) -> None:
    """Each plane in its own colour of the map, the far background in the far colour."""
    colours = _tile_colours(path, truth.label.shape).astype(int)
    medians = {}
    for name in ("fronto_0.37", "fronto_2.5", "fronto_5.2"):
        sel = (truth.label == truth.names.index(name)) & truth.interior
        medians[name] = np.median(colours[sel], axis=0)
    near, mid, far = medians["fronto_5.2"], medians["fronto_2.5"], medians["fronto_0.37"]
    # the old picture: every plane the same dark purple (a bar up to 2.7e8 mm)
    assert np.abs(far - near).sum() > 200 and np.abs(mid - near).sum() > 30, medians
    background = (truth.label == truth.names.index("fronto_0")) & truth.interior
    assert (colours[background] == FAR_RGB).all(axis=1).mean() > 0.9


def check_disparity_png(path: Path, truth: simquad.TileTruth) -> None:
    """`elphel tp` writes DSI.png: disparity on the map, texture-less tiles named."""
    colours = _tile_colours(path, truth.label.shape)
    flat = (truth.label == truth.names.index("flat")) & truth.interior
    assert (colours[flat] == NO_VALUE_RGB).all(axis=1).mean() > 0.9
    near = (truth.label == truth.names.index("fronto_5.2")) & truth.interior
    assert np.median(colours[near].astype(int), axis=0)[0] > 200  # the yellow end


def test_depth_legend_names_far_and_texture_less_tiles() -> None:
    ty, tx = 4, 5
    disparity = np.full((ty, tx), 2.0, np.float32)
    disparity[0, 0] = 0.0  # infinity
    disparity[0, 1] = 0.1  # below FAR_DISPARITY_PX
    strength = np.full((ty, tx), 0.5, np.float32)
    strength[3, :] = 0.05
    quad = QuadImages(np.full((4, 32, 40), 0.25, np.float32), bayer=None)
    r = dsi_depth({"disparity": disparity, "strength": strength}, quad, OPTICS)
    far_mm = float(OPTICS.depth_mm(np.array(FAR_DISPARITY_PX)))
    far, weak, disagree = left_out_swatches(r, far_mm)
    assert far.label == "far: disparity < 0.25 px, beyond 1227 m (2 tiles)"
    assert far.mask[0, :2].all() and far.mask.sum() == 2 and far.rgb == FAR_RGB
    assert weak.label == "no texture: strength < 0.15 (5 tiles)" and weak.mask[3].all()
    assert disagree.label == "directions disagree (0 tiles)" and not disagree.mask.any()


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


def test_tp_ply_max_disagreement(
    simulated: tuple[Path, simquad.TileTruth], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    root, _ = simulated
    args = ["tp", str(root), "--out", str(tmp_path / "d.tif"), "--ply", str(tmp_path / "c.ply")]
    with pytest.raises(SystemExit) as e:
        main([*args, "--max-disagreement", "-1"])
    assert e.value.code == 2
    assert "--max-disagreement -1; allowed: >= 0 (0 keeps every tile)" in capsys.readouterr().err
    assert main([*args, "--max-disagreement", "0", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)["depth"]
    assert out["inconsistent_tiles"] == 0 and out["max_disagreement"] is None
    assert out["points"] + out["weak_tiles"] + out["infinite_tiles"] == out["tiles"]
