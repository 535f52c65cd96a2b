"""Quad directory reading and the `elphel tp` command."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import tifffile

from elphel_host.cli import main
from elphel_host.errors import InputFormatError
from elphel_host.tp import dsi, io
from elphel_host.tp.config import TpConfig
from elphel_host.tp.images import QuadImages
from elphel_sim import quad as simquad


@pytest.fixture(scope="module")
def quad_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    rig = simquad.QuadRig(width=192, height=128)
    root, _ = simquad.simulate_quad_dir(tmp_path_factory.mktemp("q"), rig, seed=5)
    return root


def test_read_quad_dir(quad_dir: Path) -> None:
    qs = io.read_quad_dir(quad_dir)
    assert qs.quad.images.shape == (4, 128, 192)
    assert qs.quad.bayer == "GRBG"
    assert qs.quad.images.min() >= 0.0 and qs.quad.images.max() <= 1.0


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda m: m.update(version=2), "version=2; allowed: 1"),
        (lambda m: m.update(bayer="XYZW"), "bayer='XYZW'"),
        (lambda m: m["cameras"].pop(), "must list 4 cameras"),
        (lambda m: m["cameras"][2].update(file="nope.tif"), r"cameras\[2\].file"),
        (lambda m: m["cameras"][1].update(position=[1]), r"cameras\[1\].position"),
    ],
)
def test_bad_quad_dir_is_rejected(quad_dir: Path, tmp_path: Path, edit, message: str) -> None:
    manifest = json.loads((quad_dir / "quad.json").read_text())
    for i in range(4):
        (tmp_path / f"cam{i}.tif").write_bytes((quad_dir / f"cam{i}.tif").read_bytes())
    edit(manifest)
    (tmp_path / "quad.json").write_text(json.dumps(manifest))
    with pytest.raises(InputFormatError, match=message):
        io.read_quad_dir(tmp_path)


def test_missing_manifest(tmp_path: Path) -> None:
    with pytest.raises(InputFormatError, match=r"no quad\.json"):
        io.read_quad_dir(tmp_path)


def test_cli_json(quad_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "dsi.tif"
    ml = tmp_path / "ml.tiff"
    tex = tmp_path / "texture.tif"
    args = [
        "tp",
        str(quad_dir),
        "--out",
        str(out),
        "--json",
        "--ml-data",
        str(ml),
        "--texture",
        str(tex),
    ]
    code = main(args)
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert result["tiles_x"] == 24 and result["tiles_y"] == 16
    layers, _ = dsi.read_dsi(out)
    for name in ("disparity", "strength", "disparity_hor", "disparity_vert"):
        assert layers[name].shape == (16, 24)
    tiles, other, _ = dsi.read_ml_data(ml)
    assert tiles.shape == (16, 24, 9, 9, 4)
    assert np.allclose(other[..., 0], layers["target_disparity"])
    rgba = tifffile.imread(tex)
    assert rgba.shape == (128, 192, 4) and rgba.dtype == np.float32
    assert rgba[..., 3].min() >= 0.0 and rgba[..., 3].max() <= 1.0


def test_cli_bad_dir_exit_1(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["tp", str(tmp_path), "--out", str(tmp_path / "x.tif")]) == 1
    assert "no quad.json" in capsys.readouterr().err


def test_config_rejects_bad_values() -> None:
    with pytest.raises(ValueError, match=r"radius=9; allowed: 1\.\.7"):
        TpConfig(radius=9)
    with pytest.raises(InputFormatError, match=r"shape \(4, H, W\)"):
        QuadImages(np.zeros((3, 8, 8), dtype=np.float32))
