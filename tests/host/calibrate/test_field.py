"""`elphel calibrate field`: a quad's drift found from ordinary scenes and removed.

The simulator's calibration rig (`elphel_sim.calib_rig`) with its true calibration; the
same cameras then drift (each of cameras 1-3 turned and zoomed by 0.3-5 px at the image's
edge) and `elphel_sim.calib_scene` renders two of the quad's standard scenes through the
drifted cameras. The check is against the truth: where the refined calibration puts each
camera's tile of a point at infinity against where the drifted camera sees that point.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from elphel_host.cli import main as elphel_main
from elphel_host.tp.calibrated import CalibratedGeometry, read_calibration
from elphel_sim.calib_rig import CalibRig, make_rig
from elphel_sim.calib_scene import (
    drifted_rig,
    misalignment_px,
    random_drift_px,
    rectified_rig,
    render_raw_quad,
    write_raw_quad_dir,
    write_true_calibration,
)
from elphel_sim.quad import standard_scene

W, H = 640, 480


@pytest.fixture(scope="module")
def drifted_quads(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[Path], CalibRig]:
    """The rig's calibration, two scenes through its drifted cameras, the drifted rig."""
    root = tmp_path_factory.mktemp("field")
    rig = make_rig(W, H, seed=0)
    calib = write_true_calibration(root / "calib", rig).parent
    moved = drifted_rig(rig, random_drift_px(5.0, seed=4))
    quads = []
    for seed in (0, 1):
        scene = standard_scene(rectified_rig(moved), seed=seed)
        raw = render_raw_quad(scene, moved, seed=seed + 1)
        quads.append(write_raw_quad_dir(root / f"quad{seed}", raw, moved, calibration=calib))
    return calib, quads, moved


def test_field_calibration_removes_drifts_of_up_to_5_px(
    drifted_quads: tuple[Path, list[Path], CalibRig],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    calib, quads, moved = drifted_quads
    truth = CalibratedGeometry.from_cameras([(c.lens, c.R, c.t_mm) for c in moved.cameras])
    before = misalignment_px(read_calibration(calib), truth)
    assert before.min() > 1.0  # the drift is there
    out = tmp_path / "calib2"
    argv = [*map(str, quads), "--calibration", str(calib), "--out", str(out), "--json"]
    assert elphel_main(["calibrate", "field", *argv]) == 0
    result = json.loads(capsys.readouterr().out)
    after = misalignment_px(read_calibration(out), truth)
    assert after.max() <= 0.02, after
    assert result["mismatch_before_px"] > 1.0
    assert result["mismatch_after_px"] <= 0.02
    assert result["calibration"] == str(out / "calibration.json")
    assert result["infinity_tiles"] > 100 and result["tiles"] > result["infinity_tiles"]
    assert result["cameras"][0]["zoom_ppm"] == 0.0
    doc = json.loads((out / "calibration.json").read_text())
    assert doc["field"]["iterations"] == result["iterations"]
    assert np.allclose(doc["cameras"][0]["R"], np.eye(3))
    for n in range(4):
        assert (out / f"cam{n}.yml").is_file()


def test_quads_of_another_size_than_the_calibration_are_refused(
    drifted_quads: tuple[Path, list[Path], CalibRig],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    other = write_true_calibration(tmp_path / "small", make_rig(320, 240, seed=0)).parent
    quad = drifted_quads[1][0]
    argv = [str(quad), "--calibration", str(other), "--out", str(tmp_path / "out")]
    assert elphel_main(["calibrate", "field", *argv]) == 1
    err = capsys.readouterr().err
    assert "images of 640x480, the calibration is for 320x240" in err
    assert not (tmp_path / "out").exists()


def test_quads_without_texture_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = make_rig(192, 128, seed=0)
    calib = write_true_calibration(tmp_path / "calib", rig).parent
    blank = np.full((4, 128, 192), 2000, dtype=np.uint16)
    quad = write_raw_quad_dir(tmp_path / "blank", blank, rig)
    argv = [str(quad), "--calibration", str(calib), "--out", str(tmp_path / "out")]
    assert elphel_main(["calibrate", "field", *argv]) == 1
    err = capsys.readouterr().err
    assert "0 tiles with texture" in err and "allowed: at least 50" in err
