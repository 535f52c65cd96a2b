"""`elphel_sim.calib_scene`: the quad's scene through the calibration rig's own cameras."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import tifffile

from elphel_host.calibrate.camera_model import CameraModel
from elphel_host.tp.calibrated import CalibratedGeometry
from elphel_sim.calib_rig import QUAD_POSITIONS, CalibRig, RigCamera, SmoothResidual, make_rig
from elphel_sim.calib_scene import (
    camera_centres_mm,
    drifted_rig,
    misalignment_px,
    random_drift_px,
    rectified_rig,
    render_raw_quad,
)
from elphel_sim.quad import render_quad, standard_scene

W, H = 192, 128


def ideal_rig(focal_px: float, baseline_mm: float) -> CalibRig:
    cameras = []
    for px, py in QUAD_POSITIONS:
        lens = CameraModel(W, H, focal_px, focal_px, (W - 1) / 2, (H - 1) / 2)
        centre = baseline_mm * np.array([px + 0.5, py + 0.5, 0.0])
        cameras.append(RigCamera(lens, SmoothResidual(W, H), np.eye(3), -centre))
    return CalibRig(tuple(cameras))


def test_ideal_cameras_record_what_the_pinhole_renderer_does() -> None:
    rig = ideal_rig(150.0, 150.0)
    ideal = rectified_rig(rig)
    assert ideal.intrinsics.focal_length_px == pytest.approx(150.0)
    assert ideal.baseline_mm == pytest.approx(150.0)
    scene = standard_scene(ideal, seed=2)
    # same rays, same footprints, same texture filter: the same numbers
    assert np.array_equal(render_raw_quad(scene, rig, seed=None), render_quad(scene, seed=None))


def test_the_rig_is_centred_on_the_scenes_origin() -> None:
    rig = make_rig(W, H, seed=1, baseline_mm=120.0)
    centres = camera_centres_mm(rig)
    assert np.allclose(centres.mean(axis=0), 0.0, atol=1e-9)
    assert np.allclose(centres[:, :2] / 120.0, QUAD_POSITIONS, atol=1e-9)
    assert rectified_rig(rig).baseline_mm == pytest.approx(120.0)


def test_the_scene_must_be_for_the_rigs_image_size() -> None:
    rig = make_rig(W, H, seed=1)
    scene = standard_scene(rectified_rig(make_rig(2 * W, 2 * H, seed=1)), seed=0)
    with pytest.raises(ValueError, match="rig of 192x128 images, scene for 384x256"):
        render_raw_quad(scene, rig)


def test_a_drift_turns_and_zooms_cameras_1_to_3_by_the_pixels_asked() -> None:
    rig = make_rig(W, H, seed=1)
    still = drifted_rig(rig, np.zeros((4, 4)))
    assert all(
        np.allclose(a.R, b.R) and a.lens == b.lens
        for a, b in zip(still.cameras, rig.cameras, strict=True)
    )
    drift = np.zeros((4, 4))
    drift[1, 1] = 1.0  # camera 1's azimuth: 1 px at the centre
    moved = drifted_rig(rig, drift)
    far = np.array([[0.0, 0.0, 1e9]])  # a point far along camera 0's axis
    shift = moved.cameras[1].project(far) - rig.cameras[1].project(far)
    assert abs(shift[0, 0]) == pytest.approx(1.0, abs=0.02) and abs(shift[0, 1]) < 0.02
    assert all(
        moved.cameras[k] is rig.cameras[k] or moved.cameras[k].lens == rig.cameras[k].lens
        for k in (0, 2, 3)
    )
    # the camera turns about its own centre
    assert np.allclose(
        -moved.cameras[1].R.T @ moved.cameras[1].t_mm, -rig.cameras[1].R.T @ rig.cameras[1].t_mm
    )


def test_random_drifts_lie_in_the_range_asked() -> None:
    drift = random_drift_px(5.0, seed=3)
    assert np.all(drift[0] == 0)
    assert np.all((np.abs(drift[1:]) >= 0.3) & (np.abs(drift[1:]) <= 5.0))
    with pytest.raises(ValueError, match="allowed: 0 < min_px <= max_px"):
        random_drift_px(0.1, seed=0)


def test_the_misalignment_of_a_drift_is_about_its_pixels() -> None:
    rig = make_rig(W, H, seed=1)
    drift = np.zeros((4, 4))
    drift[2, 0] = 0.5  # camera 2's tilt: 0.5 px
    truth = CalibratedGeometry.from_cameras(
        [(c.lens, c.R, c.t_mm) for c in drifted_rig(rig, drift).cameras]
    )
    got = CalibratedGeometry.from_cameras([(c.lens, c.R, c.t_mm) for c in rig.cameras])
    assert np.allclose(misalignment_px(truth, truth), 0.0, atol=1e-9)
    error = misalignment_px(got, truth)
    assert error[1] == pytest.approx(0.5, abs=0.05) and error[0] < 1e-6 and error[2] < 1e-6


def test_calib_scene_drifts_the_cameras_it_renders_through(tmp_path: Path) -> None:
    from elphel_sim.cli import main as sim_main

    size = ["--width", str(W), "--height", str(H)]
    assert sim_main(["calib-scene", str(tmp_path / "still"), *size]) == 0
    argv = ["calib-scene", str(tmp_path / "moved"), "--drift-px", "2", "--drift-seed", "3"]
    assert sim_main([*argv, *size]) == 0
    truth = json.loads((tmp_path / "moved" / "truth.json").read_text())
    assert np.allclose(truth["drift_px"], random_drift_px(2.0, seed=3))
    still_truth = json.loads((tmp_path / "still" / "truth.json").read_text())
    assert "drift_px" not in still_truth
    label, names = np.asarray(still_truth["label"]), still_truth["names"]
    near = label == names.index("fronto_2.5")  # each tile names the region it sees
    assert near.sum() > 20
    assert np.allclose(np.asarray(still_truth["disparity"])[near], 2.5, atol=1e-6)
    still, moved = (tifffile.imread(tmp_path / d / "cam1.tif") for d in ("still", "moved"))
    assert np.mean(np.abs(still.astype(float) - moved)) > 10  # the same scene, moved
