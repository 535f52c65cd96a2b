"""The calibration in other tools' formats, each stating what accuracy it loses.

- mrcal ``camN.cameramodel``: LENSMODEL_OPENCV8 is this model exactly (lossless); the
  extrinsics ``rt_cam_ref`` (rotation vector, translation in mm) have camera 0 as the
  reference.
- COLMAP ``cameras.txt``: FULL_OPENCV is this model exactly (lossless); COLMAP puts
  (0, 0) at the first pixel's corner, so cx and cy gain half a pixel. The rig's poses are
  not part of cameras.txt: they stay in calibration.json and camN.yml.
- Kalibr ``camchain.yaml``: pinhole with radtan (k1 k2 p1 p2) cannot hold k3..k6, so each
  camera's radtan model is fitted to this one's projection over the image (less a 5 %
  border); the fit's residual (RMS and largest, px) is the accuracy lost, per camera. ``T_cn_cnm1``
  takes camera n-1's frame into camera n's, translation in metres (Kalibr's unit).

None of these formats (nor OpenCV's camN.yml) holds a residual grid: when the solve kept
one, each camera's grid size (RMS and largest offset over the image, px) is what the
lossless ones lose, and Kalibr's fit is made to the whole model, grid included.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from elphel_host.calibrate.camera_model import CameraModel, rotation_vector
from elphel_host.calibrate.quality import pixel_grid
from elphel_host.calibrate.solve import MARGIN, Calibration

FloatArray = NDArray[np.float64]


def _floats(values: Iterable[Any]) -> str:
    return ", ".join(repr(float(v)) for v in values)


def mrcal_cameramodel(lens: CameraModel, rotation: FloatArray, t_mm: FloatArray) -> str:
    """One camera as an mrcal ``.cameramodel`` (a Python-literal dict)."""
    intrinsics = [lens.fx, lens.fy, lens.cx, lens.cy, *lens.distortion]
    extrinsics = [*rotation_vector(rotation), *np.asarray(t_mm, dtype=np.float64)]
    return (
        "# written by elphel calibrate solve: camera 0 is the reference, translation in mm\n"
        "{\n"
        "    'lensmodel': 'LENSMODEL_OPENCV8',\n"
        f"    'intrinsics': [{', '.join(repr(float(v)) for v in intrinsics)}],\n"
        f"    'extrinsics': [{', '.join(repr(float(v)) for v in extrinsics)}],\n"
        f"    'imagersize': [{lens.width}, {lens.height}],\n"
        "}\n"
    )


def colmap_cameras(lenses: list[CameraModel]) -> str:
    """COLMAP's ``cameras.txt``, one FULL_OPENCV camera per lens (ids from 1)."""
    lines = [
        "# Camera list with one line of data per camera:",
        "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
    ]
    for n, lens in enumerate(lenses, start=1):
        params = [lens.fx, lens.fy, lens.cx + 0.5, lens.cy + 0.5, *lens.distortion]
        lines.append(
            f"{n} FULL_OPENCV {lens.width} {lens.height} "
            + " ".join(repr(float(p)) for p in params)
        )
    return "\n".join(lines) + "\n"


def fit_radtan(lens: CameraModel, *, step_px: float = 16.0) -> tuple[CameraModel, float, float]:
    """The pinhole + (k1, k2, p1, p2) model nearest ``lens``; its RMS and largest error (px).

    Fitted and measured over the image less a border of `MARGIN` of each side, as the
    calibration's own quality measures are.
    """
    pixels = pixel_grid(lens.width, lens.height, step_px=step_px, margin=MARGIN)
    rays = lens.rays(pixels, strict=False)
    ok = np.isfinite(rays).all(axis=1)
    points = np.column_stack([rays[ok], np.ones(int(ok.sum()))])
    target = pixels[ok]

    def model(p: FloatArray) -> CameraModel:
        return CameraModel.from_vector(lens.width, lens.height, np.concatenate([p, np.zeros(4)]))

    def residual(p: FloatArray) -> FloatArray:
        out: FloatArray = (model(p).project(points) - target).ravel()
        return out

    start = np.array([lens.fx, lens.fy, lens.cx, lens.cy, *lens.distortion[:4]])
    fit = least_squares(residual, start, x_scale="jac")
    err = np.linalg.norm(residual(fit.x).reshape(-1, 2), axis=1)
    return model(fit.x), float(np.sqrt(np.mean(err**2))), float(err.max())


def kalibr_camchain(cal: Calibration) -> tuple[str, list[dict[str, float]]]:
    """Kalibr's ``camchain.yaml`` and, per camera, the accuracy its radtan model loses."""
    lines, losses = [], []
    for n, cam in enumerate(cal.cameras):
        fitted, rms, worst = fit_radtan(cam.lens)
        losses.append({"rms_px": rms, "max_px": worst})
        lines += [
            f"cam{n}:",
            "  camera_model: pinhole",
            f"  intrinsics: [{_floats((fitted.fx, fitted.fy, fitted.cx, fitted.cy))}]",
            "  distortion_model: radtan",
            f"  distortion_coeffs: [{_floats(fitted.distortion[:4])}]",
            f"  resolution: [{fitted.width}, {fitted.height}]",
        ]
        if n > 0:
            prev = cal.cameras[n - 1]
            rot = cam.R @ prev.R.T
            t_m = (cam.t_mm - rot @ prev.t_mm) / 1000.0
            matrix = np.eye(4)
            matrix[:3, :3], matrix[:3, 3] = rot, t_m
            lines.append("  T_cn_cnm1:")
            lines += [f"  - [{_floats(row)}]" for row in matrix]
    return "\n".join(lines) + "\n", losses


def write_exports(cal: Calibration, out_dir: str | Path) -> dict[str, object]:
    """Write ``exports/`` (mrcal, COLMAP, Kalibr); return what was written and what it loses."""
    out = Path(out_dir) / "exports"
    out.mkdir(parents=True, exist_ok=True)
    for n, cam in enumerate(cal.cameras):
        (out / f"cam{n}.cameramodel").write_text(mrcal_cameramodel(cam.lens, cam.R, cam.t_mm))
    (out / "cameras.txt").write_text(colmap_cameras([c.lens for c in cal.cameras]))
    chain, losses = kalibr_camchain(cal)
    (out / "camchain.yaml").write_text(chain)
    grid_loss = grid_losses(cal)
    return {
        "opencv": {"files": [f"cam{n}.yml" for n in range(len(cal.cameras))], "loss_px": grid_loss},
        "mrcal": {
            "files": [f"exports/cam{n}.cameramodel" for n in range(len(cal.cameras))],
            "loss_px": grid_loss,
        },
        "colmap": {"file": "exports/cameras.txt", "loss_px": grid_loss},
        "kalibr": {"file": "exports/camchain.yaml", "loss_px": losses},
    }


def grid_losses(cal: Calibration) -> float | list[dict[str, float]]:
    """0.0 without residual grids, else per camera its grid's RMS and largest offset (px)."""
    if all(c.lens.residual is None for c in cal.cameras):
        return 0.0
    out = []
    for cam in cal.cameras:
        rms, top = (0.0, 0.0) if cam.lens.residual is None else cam.lens.residual.size_px()
        out.append({"rms_px": rms, "max_px": top})
    return out
