"""The demo's calibration step: a quad calibrated from board views, depth from raw images.

The scores are checked on a made-up truth; the whole step runs once against the
simulator (`elphel-sim up --scenario calib-small`, `elphel calibrate capture` and
`solve`, `elphel-sim calib-scene`, `elphel tp`) and must calibrate well enough that the
raw images' DSI is close to that of ideal cameras, far from the raw images read as ideal,
and the planes' depth within 0.5 % of the truth.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from elphel_host.progress import ProgressLine
from elphel_sim.demo import calib as demo_calib
from elphel_sim.demo import rig as demo_rig
from elphel_sim.demo.calib import calib_step, depth_errors, dsi_rms_error_px, true_depth_mm
from elphel_sim.demo.rig import DemoProgress


def made_up_truth() -> dict[str, Any]:
    """A 6x8 tile grid: background at infinity, a plane at 2 px (left), one at 4 px (right)."""
    disparity = np.zeros((6, 8))
    label = np.full((6, 8), 2)
    disparity[1:5, 1:4], label[1:5, 1:4] = 2.0, 0
    disparity[1:5, 4:7], label[1:5, 4:7] = 4.0, 1
    interior = np.ones((6, 8), dtype=bool)
    interior[:, 3:5] = False  # the planes' common edge
    return {
        "disparity": disparity.tolist(),
        "label": label.tolist(),
        "names": ["near_left", "near_right", "background"],
        "interior": interior.tolist(),
        "textured": np.ones((6, 8), dtype=bool).tolist(),
        "focal_length_px": 1000.0,
        "baseline_mm": 150.0,
    }


def test_the_depth_error_is_per_plane_against_f_b_over_d() -> None:
    truth = made_up_truth()
    true_mm = true_depth_mm(truth)
    assert true_mm[2, 2] == pytest.approx(75_000.0) and np.isinf(true_mm[0, 0])
    depth = true_mm.copy()
    depth[1:5, 1:3] *= 1.01  # the left plane 1 % too far
    depth[1:5, 5:7] *= 0.995  # the right one 0.5 % too near
    depth[1, 1] = np.nan  # a tile left out of the cloud
    depth[0, 0] = 1e6  # the background is not scored (its depth is infinite)
    got = depth_errors(depth, truth)
    assert got["planes_pct"] == pytest.approx({"near_left": 1.0, "near_right": -0.5})
    assert got["tiles"] == 7 + 8  # interior tiles with a depth
    assert got["median_abs_pct"] == pytest.approx(0.5)  # 8 tiles at 0.5 %, 7 at 1 %


def test_the_dsi_error_is_over_textured_tiles_inside_one_region() -> None:
    truth = made_up_truth()
    disparity = np.asarray(truth["disparity"]) + 0.03
    disparity[:, 3:5] += 5.0  # edge tiles do not count
    textured = np.asarray(truth["textured"])
    textured[0, :] = False
    truth["textured"] = textured.tolist()
    disparity[0, :] = -9.0  # nor do texture-less ones
    assert dsi_rms_error_px(disparity, truth) == pytest.approx(0.03)


@pytest.mark.slow  # the whole step: two and a half minutes on two quiet cores
def test_the_demo_calibrates_the_quad_and_gets_depth_from_its_raw_images(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(
        demo_rig, "DEMO_PROGRESS", DemoProgress(ProgressLine(io.StringIO()), total=1)
    )
    got = calib_step(tmp_path, seed=0)
    assert got["views"] == demo_calib.VIEWS  # every suggested pose gave a view
    assert got["rms_px"] < 0.02  # the corners' noise
    rms = got["dsi_rms_error_px"]
    assert rms["calibrated"] <= 1.3 * rms["rectified"]  # nearly as good as ideal cameras
    assert rms["as_ideal"] > 30 * rms["calibrated"]  # without the calibration: noise
    planes = got["depth_error_pct"]
    for plane in ("fronto_2.5", "fronto_5.2", "slanted"):
        assert abs(planes[plane]) <= 0.5, planes
    for picture in (got["residuals_picture"], got["picture"]):
        with Image.open(picture) as im:
            assert im.width > 400
