"""The exports: mrcal and COLMAP hold the model exactly, Kalibr's radtan states its loss."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
import yaml

from elphel_host.calibrate.camera_model import rotation_matrix
from elphel_host.calibrate.export import write_exports
from elphel_host.calibrate.solve import Calibration, calibrate
from elphel_sim.calib_rig import board_poses, make_rig

from .conftest import BOARD, observe


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> tuple[Calibration, Path, dict]:
    rig = make_rig(640, 480, seed=51)
    obs = observe(rig, board_poses(rig, BOARD, 10, seed=52, min_cameras=2), noise_px=0.01, seed=53)
    cal = calibrate(obs, cross_validate=False)
    out = tmp_path_factory.mktemp("calib")
    return cal, out, write_exports(cal, out)


def test_mrcal_models_hold_the_model_exactly(exported: tuple) -> None:
    cal, out, _ = exported
    for n, cam in enumerate(cal.cameras):
        model = ast.literal_eval((out / "exports" / f"cam{n}.cameramodel").read_text())
        assert model["lensmodel"] == "LENSMODEL_OPENCV8"
        assert model["intrinsics"] == [
            cam.lens.fx,
            cam.lens.fy,
            cam.lens.cx,
            cam.lens.cy,
            *cam.lens.distortion,
        ]
        assert np.allclose(rotation_matrix(np.array(model["extrinsics"][:3])), cam.R, atol=1e-12)
        assert np.allclose(model["extrinsics"][3:], cam.t_mm)


def test_colmap_cameras_shift_the_pixel_origin(exported: tuple) -> None:
    cal, out, _ = exported
    rows = [
        line.split()
        for line in (out / "exports" / "cameras.txt").read_text().splitlines()
        if not line.startswith("#")
    ]
    assert [r[:4] for r in rows] == [[str(n + 1), "FULL_OPENCV", "640", "480"] for n in range(4)]
    params = np.array(rows[2][4:], dtype=np.float64)
    lens = cal.cameras[2].lens
    assert np.allclose(params, [lens.fx, lens.fy, lens.cx + 0.5, lens.cy + 0.5, *lens.distortion])


def test_kalibr_chain_states_its_loss(exported: tuple) -> None:
    cal, out, info = exported
    chain = yaml.safe_load((out / "exports" / "camchain.yaml").read_text())
    t = np.array(chain["cam3"]["T_cn_cnm1"])
    rot = cal.cameras[3].R @ cal.cameras[2].R.T
    assert np.allclose(t[:3, :3], rot)
    assert np.allclose(t[:3, 3] * 1000, cal.cameras[3].t_mm - rot @ cal.cameras[2].t_mm)
    losses = info["kalibr"]["loss_px"]
    assert len(losses) == 4
    assert all(0 < loss["rms_px"] < 0.1 and loss["max_px"] >= loss["rms_px"] for loss in losses)
    assert info["mrcal"]["loss_px"] == 0.0 and info["colmap"]["loss_px"] == 0.0
