"""From board views to depth on raw images, through the commands docs/calibration.md gives.

`elphel-sim calib-views`, `elphel calibrate solve`, `elphel-sim calib-scene --calibration`
(the same rig: same size and seed) and `elphel tp --ply`: the DSI of the raw images with
the solved calibration against the same scene rendered rectified, and a plane's depth.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from elphel_host.cli import main as elphel_main
from elphel_host.depth.products import read_depth_tiff
from elphel_host.tp.dsi import read_dsi
from elphel_sim.cli import main as sim_main

pytestmark = pytest.mark.slow  # renders 16 quad views and solves them (about a minute)

SIZE = ["--width", "640", "--height", "480", "--seed", "0"]


def run(main, argv: list[str], capsys: pytest.CaptureFixture[str]) -> dict:
    assert main([*argv, "--json"]) == 0
    out: dict = json.loads(capsys.readouterr().out)
    return out


def test_raw_images_with_the_solved_calibration(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    views, calib, raw, rect = (tmp_path / n for n in ("views", "calib", "raw", "rect"))
    run(sim_main, ["calib-views", str(views), "--views", "16", *SIZE], capsys)
    argv = ["calibrate", "solve", str(views), "--pattern", "checkerboard:9x6:25"]
    solved = run(elphel_main, [*argv, "--out", str(calib), "--no-cross-validation"], capsys)
    assert solved["rms_px"] < 0.02
    argv = ["calib-scene", str(raw), "--calibration", str(calib), "--rectified", str(rect)]
    run(sim_main, [*argv, *SIZE], capsys)
    assert json.loads((raw / "quad.json").read_text())["calibration"] == "calibration.json"
    truth = json.loads((raw / "truth.json").read_text())
    scored = np.array(truth["interior"]) & np.array(truth["textured"])
    errors = {}
    for name, root in (("raw", raw), ("rect", rect)):
        out = run(elphel_main, ["tp", str(root), "--out", str(tmp_path / f"{name}.tif")], capsys)
        disparity = read_dsi(out["dsi"])[0]["disparity"]
        errors[name] = np.sqrt(np.mean((disparity - np.array(truth["disparity"]))[scored] ** 2))
    assert errors["rect"] < 0.04 and errors["raw"] <= 1.2 * errors["rect"]

    ply = tmp_path / "cloud.ply"
    argv = ["tp", str(raw), "--out", str(tmp_path / "d.tif"), "--ply", str(ply)]
    out = run(elphel_main, argv, capsys)
    depth_mm = read_depth_tiff(out["depth"]["depth_tiff"])[0]
    true_mm = truth["focal_length_px"] * truth["baseline_mm"] / np.array(truth["disparity"])
    plane = scored & np.isclose(np.array(truth["disparity"]), 2.5)
    assert plane.sum() > 100
    assert abs(np.nanmedian(depth_mm[plane] / true_mm[plane]) - 1) <= 0.005
