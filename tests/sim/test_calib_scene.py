"""`elphel_sim.calib_scene`: the quad's scene through the calibration rig's own cameras."""

from __future__ import annotations

import numpy as np
import pytest

from elphel_host.calibrate.camera_model import CameraModel
from elphel_sim.calib_rig import QUAD_POSITIONS, CalibRig, RigCamera, SmoothResidual, make_rig
from elphel_sim.calib_scene import camera_centres_mm, rectified_rig, render_raw_quad
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
