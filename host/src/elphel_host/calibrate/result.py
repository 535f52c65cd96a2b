"""The calibration directory: calibration.json and camN.yml (docs/calibration.md), one owner.

calibration.json holds ``version``, ``pattern``, ``rms_px`` and per camera the model
(``width``, ``height``, ``fx``, ``fy``, ``cx``, ``cy``, ``distortion``), ``R`` and
``t_mm`` (camera 0's frame into this camera's), and the quality (``rms_px``, ``corners``,
``uncertainty_px``); then the views, the board's bend, the outliers, the images without
a board, the warnings and the cross-validation. camN.yml is OpenCV FileStorage YAML
(``image_width``, ``image_height``, ``camera_matrix``, ``distortion_coefficients``, and
for N > 0 ``R``, ``T`` in mm relative to camera 0).
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from elphel_host.calibrate.camera_model import CameraModel
from elphel_host.calibrate.solve import Calibration
from elphel_host.fileio import replacing, write_atomic

VERSION = 1
CALIBRATION_FILE = "calibration.json"


def calibration_json(cal: Calibration) -> dict[str, Any]:
    """The calibration.json document of ``cal``."""
    cameras = []
    for cam in cal.cameras:
        cameras.append(
            {
                **cam.lens.to_json(),
                "R": cam.R.tolist(),
                "t_mm": cam.t_mm.tolist(),
                "rms_px": cam.rms_px,
                "corners": cam.corners,
                "uncertainty_px": cam.uncertainty_px,
            }
        )
    return {
        "version": VERSION,
        "pattern": cal.pattern,
        "rms_px": cal.rms_px,
        "cameras": cameras,
        "board_warp_mm": list(cal.warp_mm),
        "views": list(cal.views),
        "outliers": [asdict(o) for o in cal.outliers],
        "missing": [{"view": v, "camera": c} for v, c in cal.missing],
        "warnings": list(cal.warnings),
        "residual_grid_fit": cal.residual_grid,
        "cross_validation": cal.cross_validation,
    }


def finite_json(value: Any) -> Any:
    """``value`` with every NaN or infinity replaced by None (JSON has neither)."""
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if isinstance(value, dict):
        return {k: finite_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(v) for v in value]
    return value


def _write_yml(
    path: Path, lens: CameraModel, rotation: np.ndarray | None, t_mm: np.ndarray | None
) -> None:
    with replacing(path, keep_suffix=True) as tmp:
        fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
        try:
            fs.write("image_width", lens.width)
            fs.write("image_height", lens.height)
            fs.write("camera_matrix", lens.camera_matrix)
            fs.write("distortion_coefficients", lens.coefficients.reshape(1, -1))
            if rotation is not None and t_mm is not None:
                fs.write("R", np.asarray(rotation, dtype=np.float64))
                fs.write("T", np.asarray(t_mm, dtype=np.float64).reshape(3, 1))
        finally:
            fs.release()


def write_calibration(
    cal: Calibration, out_dir: str | Path, *, extra: dict[str, Any] | None = None
) -> Path:
    """Write calibration.json (with ``extra`` fields) and camN.yml; return the json's path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for n, cam in enumerate(cal.cameras):
        _write_yml(out / f"cam{n}.yml", cam.lens, cam.R if n else None, cam.t_mm if n else None)
    doc = json.dumps(
        finite_json({**calibration_json(cal), **(extra or {})}), indent=1, allow_nan=False
    )
    return write_atomic(out / CALIBRATION_FILE, (doc + "\n").encode())


def read_cameras(path: str | Path) -> list[tuple[CameraModel, np.ndarray, np.ndarray]]:
    """Each camera's (model, R, t_mm) from a calibration.json."""
    doc = json.loads(Path(path).read_text())
    if doc.get("version") != VERSION:
        raise ValueError(f"{path}: version {doc.get('version')!r}; allowed: {VERSION}")
    return [
        (
            CameraModel.from_json(c),
            np.array(c["R"], dtype=np.float64),
            np.array(c["t_mm"], dtype=np.float64),
        )
        for c in doc["cameras"]
    ]


def write_updated_cameras(
    source: str | Path,
    cameras: list[tuple[CameraModel, np.ndarray, np.ndarray]],
    out_dir: str | Path,
    *,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write calibration.json ``source`` into ``out_dir`` with new cameras; return its path.

    Each camera's model, ``R`` and ``t_mm`` are replaced by ``cameras``' and ``extra``'s
    fields added; the rest of the document is kept. camN.yml are written anew.
    """
    doc = json.loads(Path(source).read_text())
    if len(doc["cameras"]) != len(cameras):
        raise ValueError(f"{source}: {len(doc['cameras'])} cameras, {len(cameras)} given")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for n, (entry, (lens, rotation, t_mm)) in enumerate(zip(doc["cameras"], cameras, strict=True)):
        entry.update({**lens.to_json(), "R": rotation.tolist(), "t_mm": t_mm.tolist()})
        _write_yml(out / f"cam{n}.yml", lens, rotation if n else None, t_mm if n else None)
    text = json.dumps(finite_json({**doc, **(extra or {})}), indent=1, allow_nan=False)
    return write_atomic(out / CALIBRATION_FILE, (text + "\n").encode())
