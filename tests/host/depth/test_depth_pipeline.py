"""`elphel depth` on a small simulated quad burst of the relief scene; the quad-burst format."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from elphel_host.burst.io import read_quad_burst
from elphel_host.burst.manifest import read_manifest, write_manifest
from elphel_host.cli import main
from elphel_host.cloud.compare import compare_clouds
from elphel_host.cloud.ply import read_ply
from elphel_host.errors import InputFormatError
from elphel_host.mfsr.local_motion import ParallaxModel, disparity_field
from elphel_host.tp.dsi import read_dsi
from elphel_sim import relief
from elphel_sim.quad import QuadRig
from elphel_sim.scenarios import QUAD_RIG_AXIS_DEG

pytestmark = pytest.mark.slow  # renders 24 quad frames of the relief scene

RIG = QuadRig(width=192, height=128)
POSITIONS = [0.0, 7.0, 15.0, 22.0, 31.0, 38.0]


@pytest.fixture(scope="module")
def burst(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("qb")
    scene = relief.relief_scene(RIG, seed=4)
    relief.simulate_quad_burst(
        root / "qb", scene, POSITIONS, axis_angle_deg=QUAD_RIG_AXIS_DEG, seed=4
    )
    relief.write_truth(root / "truth", scene, step_px=0.5)
    return root


def test_read_quad_burst(burst: Path) -> None:
    qb = read_quad_burst(burst / "qb")
    assert qb.frames == len(POSITIONS)
    assert [c.file for c in qb.manifest.cameras] == ["cam0", "cam1", "cam2", "cam3"]
    assert qb.bursts[2].frames.shape == (len(POSITIONS), 128, 192)
    assert qb.bursts[0].stage["axis_angle_deg"] == pytest.approx(QUAD_RIG_AXIS_DEG)


def test_quad_burst_that_does_not_belong_together(burst: Path, tmp_path: Path) -> None:
    bad = tmp_path / "qb"
    shutil.copytree(burst / "qb", bad)
    m = read_manifest(bad / "cam1")
    assert m is not None
    frames = list(m.frames)
    frames[2] = type(frames[2])(**{**frames[2].__dict__, "timestamp_ns": 1})
    write_manifest(bad / "cam1", type(m)(tuple(frames), m.bayer, m.optics, m.stage, m.extra))
    with pytest.raises(InputFormatError, match="frame 2 is not of one trigger"):
        read_quad_burst(bad)
    shutil.rmtree(bad / "cam3")
    with pytest.raises(InputFormatError, match=r"cameras\[3\].file='cam3' is not a burst"):
        read_quad_burst(bad)


def test_parallax_model_and_field() -> None:
    m = ParallaxModel.from_caliper([0.0, 15.0], baseline_mm=150.0, axis_angle_deg=0.0)
    assert m.shifts(2.0) == [(0.0, 0.0), (0.0, pytest.approx(0.2))]
    d = np.full((4, 6), 2.0, np.float32)
    s = np.full((4, 6), 0.5, np.float32)
    d[0, 0], s[1, 1] = np.nan, 0.0
    f = disparity_field(d, s, min_strength=0.1)
    assert np.isfinite(f).all() and np.allclose(f, 2.0)
    with pytest.raises(ValueError, match="no tile is strong enough"):
        disparity_field(d, np.zeros_like(s), min_strength=0.1)


def test_elphel_depth(burst: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    code = main(["depth", str(burst / "qb"), "--scale", "2", "--out", str(out), "--json"])
    assert code == 0
    r = json.loads(capsys.readouterr().out)
    assert r["tiles"] == 48 * 32  # fused: 384x256
    assert set(r["seconds"]) >= {"read", "prior", "fuse", "tp", "depth", "total"}
    assert r["cameras"]["cam0"]["parallax_from"] == "caliper"
    layers, _ = read_dsi(r["dsi"])
    assert np.allclose(layers["disparity_lr"], layers["disparity"] / 2, equal_nan=True)
    cloud = read_ply(r["ply"])
    assert len(cloud) == r["points"] > 0.8 * r["tiles"]
    ref = read_ply(burst / "truth" / "reference.ply")
    c = compare_clouds(cloud, ref)
    # the scene spans 57 m .. 307 m; 0.1 px of disparity is 2 % of depth at 5 px
    assert c.forward.median_mm < 0.03 * 307_000
    assert (out / "fused" / "quad.json").is_file() and (out / "depth.json").is_file()


def test_elphel_depth_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["depth", str(tmp_path), "--out", str(tmp_path / "o")]) == 1
    assert "no quad.json" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["depth", str(tmp_path), "--out", str(tmp_path / "o"), "--scale", "0"])
    assert e.value.code == 2
    with pytest.raises(SystemExit) as e:
        main(["depth", str(tmp_path), "--out", str(tmp_path / "o"), "--method", "baseline"])
    assert e.value.code == 2
    assert "give --motion global with it" in capsys.readouterr().err
