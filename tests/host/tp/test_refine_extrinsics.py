"""`elphel tp QUAD_DIR... --out-dir DIR --refine-extrinsics`: lazy-eye refinement on the fly.

A sequence of the quad's standard scenes (`elphel_sim.calib_scene`, as bench/field.py
renders them) through cameras 1-3 that drifted by 0.3-1 px per correction since the rig
was calibrated, each quad directory naming the calibration made before the drift. Run in
order, every quad refines the calibration for the next ones: checked against the
simulator's truth (where the calibration puts each camera's tile of a point at infinity
against where the drifted camera sees it) and by the DSIs' error.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from elphel_host.calibrate.field_running import RunningField
from elphel_host.calibrate.result import read_cameras
from elphel_host.cli import main as elphel_main
from elphel_host.tp.calibrated import CalibratedGeometry, read_calibration
from elphel_host.tp.dsi import read_dsi
from elphel_sim.calib_rig import make_rig
from elphel_sim.calib_scene import (
    drifted_rig,
    misalignment_px,
    random_drift_px,
    rectified_rig,
    render_raw_quad,
    write_raw_quad_dir,
    write_true_calibration,
)
from elphel_sim.quad import standard_scene, tile_truth

W, H = 640, 480
QUADS = 4


def dsi_rms_px(dsi_path: Path, truth: object) -> float:
    disparity = read_dsi(dsi_path)[0]["disparity"]
    scored = truth.interior & truth.textured  # type: ignore[attr-defined]
    err = disparity - truth.disparity  # type: ignore[attr-defined]
    return float(np.sqrt(np.mean(err[scored] ** 2)))


@pytest.mark.slow  # four quads rendered and processed: half a minute
def test_a_drifted_sequence_is_brought_back_quad_by_quad(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = make_rig(W, H, seed=0)
    calib = write_true_calibration(tmp_path / "calib", rig).parent
    moved = drifted_rig(rig, random_drift_px(1.0, seed=4))
    truths = []
    for seed in range(QUADS):
        scene = standard_scene(rectified_rig(moved), seed=seed)
        raw = render_raw_quad(scene, moved, seed=seed + 1)
        write_raw_quad_dir(tmp_path / "seq" / f"q{seed}", raw, moved, calibration=calib)
        truths.append(tile_truth(scene))
    out = tmp_path / "dsi"
    argv = ["tp", str(tmp_path / "seq"), "--out-dir", str(out), "--refine-extrinsics", "--json"]
    code = elphel_main(argv)
    stdout, stderr = capsys.readouterr()
    assert code == 0, stderr
    result = json.loads(stdout)
    assert [Path(q["quad"]).name for q in result["quads"]] == [f"q{s}" for s in range(QUADS)]
    assert result["calibration"] == str(out / "calibration.json")
    assert "q0: mismatch " in stderr  # each quad's line

    truth = CalibratedGeometry.from_cameras([(c.lens, c.R, c.t_mm) for c in moved.cameras])
    before = misalignment_px(read_calibration(calib), truth)
    after = misalignment_px(read_calibration(out / "calibration.json"), truth)
    assert before.max() > 0.8 and after.max() <= 0.02, (before, after)

    refinement = [q["refinement"] for q in result["quads"]]
    assert all(r["updated"] for r in refinement)
    first, last = refinement[0], refinement[-1]
    assert last["mismatch_before_px"] < first["mismatch_before_px"] / 10
    for r in refinement:
        assert r["mismatch_after_px"] < r["mismatch_before_px"]
    errors = [dsi_rms_px(out / f"q{s}.tif", t) for s, t in enumerate(truths)]
    assert errors[0] > 0.3  # the first quad is processed with the drifted calibration
    assert max(errors[2:]) < 0.05 and max(errors[2:]) < errors[0] / 5, errors
    doc = json.loads((out / "calibration.json").read_text())
    assert doc["field"]["quads"] == [q["quad"] for q in result["quads"]]


def test_refining_needs_calibrated_quads(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = make_rig(64, 48, seed=0)
    images = np.zeros((4, 48, 64), dtype=np.uint16)
    write_raw_quad_dir(tmp_path / "q0", images, rig)  # no calibration in quad.json
    argv = ["tp", str(tmp_path / "q0"), "--out-dir", str(tmp_path / "o"), "--refine-extrinsics"]
    assert elphel_main(argv) == 1
    assert "names no calibration" in capsys.readouterr().err


def test_refine_memory_without_refining_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as usage:
        elphel_main(["tp", str(tmp_path), "--out", "x.tif", "--refine-memory", "0.2"])
    assert usage.value.code == 2
    assert "--refine-memory: only with --out-dir" in capsys.readouterr().err


def test_a_running_field_refuses_a_quad_of_another_size(tmp_path: Path) -> None:
    from elphel_host.errors import InputFormatError
    from elphel_host.tp.images import QuadImages

    rig = make_rig(W, H, seed=0)
    running = RunningField(read_cameras(write_true_calibration(tmp_path, rig)))
    quad = QuadImages(np.zeros((4, 240, 320), dtype=np.float32), bayer=None)
    with pytest.raises(InputFormatError, match="images of 320x240, the calibration is for 640x480"):
        running.place(quad)
    with pytest.raises(ValueError, match=r"memory=1\.0"):
        RunningField(running.initial, memory=1.0)
