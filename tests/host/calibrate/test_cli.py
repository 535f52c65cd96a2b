"""`elphel calibrate solve` on a simulated views directory: files, JSON and errors."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from elphel_host.calibrate.camera_model import CameraModel
from elphel_host.calibrate.quality import projection_difference
from elphel_host.cli import main as elphel_main
from elphel_sim.cli import main as sim_main


@pytest.fixture(scope="module")
def views(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("views") / "one"
    argv = ["calib-views", str(root), "--cameras", "1", "--views", "6", "--width", "640"]
    assert sim_main([*argv, "--height", "480", "--seed", "41"]) == 0
    cv2.imwrite(str(root / "view999.png"), np.full((480, 640), 90, np.uint8))  # no board here
    return root


def test_solve_writes_the_calibration_directory(
    views: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "calib"
    code = elphel_main(
        [
            "calibrate",
            "solve",
            str(views),
            "--pattern",
            "checkerboard:9x6:25",
            "--out",
            str(out),
            "--json",
            "--no-cross-validation",
        ]
    )
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert result["calibration"] == str(out / "calibration.json")
    assert result["rms_px"] < 0.03
    assert result["missing"] == [{"view": "view999.png", "camera": 0}]
    doc = json.loads((out / "calibration.json").read_text())
    assert doc["version"] == 1 and doc["pattern"] == "checkerboard:9x6:25"
    cam = doc["cameras"][0]
    assert {"width", "height", "fx", "fy", "cx", "cy", "distortion", "R", "t_mm"} <= set(cam)
    assert cam["distortion"]["model"] == "opencv" and len(cam["distortion"]["coefficients"]) == 8
    fs = cv2.FileStorage(str(out / "cam0.yml"), cv2.FILE_STORAGE_READ)
    assert fs.getNode("image_width").real() == 640
    assert np.allclose(fs.getNode("camera_matrix").mat()[0, 0], cam["fx"])
    assert np.allclose(
        fs.getNode("distortion_coefficients").mat().ravel(), cam["distortion"]["coefficients"]
    )
    fs.release()
    for name in ("residuals.png", "coverage.png", "uncertainty.png"):
        assert cv2.imread(str(out / name)) is not None


def test_the_solved_lens_is_the_true_one(views: Path, tmp_path: Path) -> None:
    out = tmp_path / "calib"
    assert (
        elphel_main(
            [
                "calibrate",
                "solve",
                str(views),
                "--pattern",
                "checkerboard:9x6:25",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    solved = CameraModel.from_json(json.loads((out / "calibration.json").read_text())["cameras"][0])
    true = CameraModel.from_json(json.loads((views / "truth.json").read_text())["cameras"][0])
    diff = projection_difference(solved, true, margin=0.05)
    # six views of one camera, the board in the middle: 0.05 px at this coverage
    assert np.sqrt(np.nanmean(diff**2)) < 0.05


def test_wrong_pattern_size_says_how_to_count(
    views: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code = elphel_main(
        [
            "calibrate",
            "solve",
            str(views),
            "--pattern",
            "checkerboard:7x4:25",
            "--out",
            str(tmp_path / "c"),
        ]
    )
    assert code == 1
    assert "inner corners" in capsys.readouterr().err


def test_bad_spec_is_a_usage_error(views: Path, tmp_path: Path) -> None:
    with pytest.raises(SystemExit) as e:
        elphel_main(
            ["calibrate", "solve", str(views), "--pattern", "9x6", "--out", str(tmp_path / "c")]
        )
    assert e.value.code == 2


def test_a_lens_the_model_follows_gets_no_grid_and_the_summary_says_so(
    views: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "calib"
    argv = ["calibrate", "solve", str(views), "--pattern", "checkerboard:9x6:25"]
    assert elphel_main([*argv, "--out", str(out), "--no-cross-validation"]) == 0
    assert "residual grid: not kept" in capsys.readouterr().out
    doc = json.loads((out / "calibration.json").read_text())
    assert doc["residual_grid_fit"]["kept"] is False
    assert "residual_grid" not in doc["cameras"][0]
    assert doc["exports"]["opencv"]["loss_px"] == 0.0


@pytest.mark.parametrize("value", ["6", "1x4", "6x40", "fine"])
def test_a_bad_residual_grid_is_a_usage_error(
    views: Path, tmp_path: Path, value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["calibrate", "solve", str(views), "--pattern", "checkerboard:9x6:25"]
    with pytest.raises(SystemExit) as e:
        elphel_main([*argv, "--out", str(tmp_path / "c"), "--residual-grid", value])
    assert e.value.code == 2
    assert "--residual-grid" in capsys.readouterr().err
