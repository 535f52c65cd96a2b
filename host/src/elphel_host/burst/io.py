"""Burst directories (DESIGN 4.3): ``manifest.json`` version 1 + ``frames/NNNN.tif``.

Layout::

    BURST/manifest.json
    BURST/frames/0000.tif ...   16-bit, one frame each (Bayer raw or mono)

``manifest.json`` is ``{"version": 1, "frames": [{"file": "frames/0000.tif", ...}, ...]}``;
each frame entry may carry ``stage_mm``, ``caliper_mm``, ``frame`` and ``timestamp_ns``;
the top level may carry ``optics`` (``focal_length_mm``, ``pixel_pitch_um``,
``object_distance_mm``), ``stage`` (``mm_per_step``, ``axis_angle_deg``) and ``bayer``
(``"RGGB"``, ``"GRBG"``, ``"GBRG"``, ``"BGGR"`` or null). Other top-level keys are kept.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
from numpy.typing import NDArray

from elphel_host.errors import InputFormatError

BAYER_PATTERNS = ("RGGB", "GRBG", "GBRG", "BGGR")
MANIFEST = "manifest.json"
VERSION = 1

_FRAME_NUMBERS = {"stage_mm": float, "caliper_mm": float, "frame": int, "timestamp_ns": int}
_OPTICS = ("focal_length_mm", "pixel_pitch_um", "object_distance_mm")
_STAGE = ("mm_per_step", "axis_angle_deg")


@dataclass(frozen=True)
class FrameInfo:
    """One manifest frame entry."""

    file: str
    stage_mm: float | None = None
    caliper_mm: float | None = None
    frame: int | None = None
    timestamp_ns: int | None = None

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {"file": self.file}
        for k in _FRAME_NUMBERS:
            v = getattr(self, k)
            if v is not None:
                d[k] = v
        return d


@dataclass(frozen=True)
class Burst:
    """A burst directory as loaded.

    Attributes
    ----------
    frames
        (N, H, W) uint16 frames.
    infos
        The manifest's frame entries.
    bayer
        Bayer pattern or None (mono).
    optics, stage
        The optional top-level objects (empty dict when absent).
    extra
        Other top-level manifest keys, kept as they were.
    """

    frames: NDArray[np.uint16]
    infos: tuple[FrameInfo, ...]
    bayer: str | None = None
    optics: dict[str, float] = field(default_factory=dict)
    stage: dict[str, float] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    def stage_prior_px(self) -> list[tuple[float, float]] | None:
        """Per-frame image shift (dy, dx) in px predicted from stage and optics, if known.

        The camera moving by ``d`` mm along the stage axis (angle ``axis_angle_deg`` from
        the sensor's x axis) shifts the image of the object plane by
        ``d * f / (Z - f) / pitch`` px along the same direction.
        """
        f = self.optics.get("focal_length_mm")
        p = self.optics.get("pixel_pitch_um")
        z = self.optics.get("object_distance_mm")
        if f is None or p is None or z is None or z <= f:
            return None
        pos: list[float] = []
        for i in self.infos:
            v = i.caliper_mm if i.caliper_mm is not None else i.stage_mm
            if v is None:
                return None
            pos.append(v)
        px_per_mm = f / (z - f) * 1000.0 / p
        theta = math.radians(self.stage.get("axis_angle_deg", 0.0))
        p0 = pos[0]
        return [
            (
                (v - p0) * px_per_mm * math.sin(theta),
                (v - p0) * px_per_mm * math.cos(theta),
            )
            for v in pos
        ]


def _fail(path: Path, what: str, value: Any, allowed: str) -> InputFormatError:
    return InputFormatError(f"{path}: {what}={value!r}; allowed: {allowed}")


def _number_map(path: Path, name: str, obj: Any, keys: Sequence[str]) -> dict[str, float]:
    if obj is None:
        return {}
    if not isinstance(obj, dict):
        raise _fail(path, name, obj, "an object")
    out: dict[str, float] = {}
    for k, v in obj.items():
        if k not in keys:
            raise _fail(path, f"{name}.{k}", v, f"keys {', '.join(keys)}")
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise _fail(path, f"{name}.{k}", v, "a finite number")
        out[k] = float(v)
    for k in ("focal_length_mm", "pixel_pitch_um", "object_distance_mm", "mm_per_step"):
        if k in out and out[k] <= 0:
            raise _fail(path, f"{name}.{k}", out[k], "> 0")
    return out


def _frame_info(path: Path, i: int, entry: Any, root: Path) -> FrameInfo:
    if not isinstance(entry, dict):
        raise _fail(path, f"frames[{i}]", entry, 'an object with "file"')
    file = entry.get("file")
    if not isinstance(file, str) or not file:
        raise _fail(path, f"frames[{i}].file", file, "a relative path such as frames/0000.tif")
    if Path(file).is_absolute() or ".." in Path(file).parts:
        raise _fail(path, f"frames[{i}].file", file, "a path inside the burst directory")
    if not (root / file).is_file():
        raise InputFormatError(f"{path}: frames[{i}].file={file!r} does not exist in {root}")
    kw: dict[str, Any] = {}
    for k, typ in _FRAME_NUMBERS.items():
        v = entry.get(k)
        if v is None:
            continue
        ok = (
            (isinstance(v, int) and not isinstance(v, bool))
            if typ is int
            else (isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v))
        )
        if not ok:
            raise _fail(path, f"frames[{i}].{k}", v, "an integer" if typ is int else "a number")
        kw[k] = typ(v)
    return FrameInfo(file=file, **kw)


def read_burst(path: str | Path) -> Burst:
    """Load and validate a burst directory.

    Raises
    ------
    InputFormatError
        Naming the file, the field, the value and what is allowed, when the directory
        does not follow DESIGN 4.3.
    """
    root = Path(path)
    mpath = root / MANIFEST
    if not mpath.is_file():
        raise InputFormatError(f"{root}: no {MANIFEST} (expected a burst directory, DESIGN 4.3)")
    try:
        m = json.loads(mpath.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputFormatError(f"{mpath}: not valid JSON ({e})") from e
    if not isinstance(m, dict):
        raise _fail(mpath, "top level", type(m).__name__, "an object")
    if m.get("version") != VERSION:
        raise _fail(mpath, "version", m.get("version"), str(VERSION))
    entries = m.get("frames")
    if not isinstance(entries, list) or not entries:
        raise _fail(mpath, "frames", entries, "a non-empty list of frame objects")
    bayer = m.get("bayer")
    if bayer is not None and bayer not in BAYER_PATTERNS:
        raise _fail(mpath, "bayer", bayer, f"null or one of {', '.join(BAYER_PATTERNS)}")
    optics = _number_map(mpath, "optics", m.get("optics"), _OPTICS)
    stage = _number_map(mpath, "stage", m.get("stage"), _STAGE)
    infos = tuple(_frame_info(mpath, i, e, root) for i, e in enumerate(entries))
    images: list[NDArray[Any]] = []
    for i, info in enumerate(infos):
        fpath = root / info.file
        try:
            img = tifffile.imread(fpath)
        except Exception as e:  # tifffile raises many kinds on a damaged file
            raise InputFormatError(f"{fpath}: not a readable TIFF ({e})") from e
        if img.dtype != np.uint16:
            raise _fail(fpath, "dtype", str(img.dtype), "uint16")
        if img.ndim != 2:
            raise _fail(fpath, "shape", img.shape, "a 2-D (single-channel) image")
        if images and img.shape != images[0].shape:
            raise _fail(fpath, "shape", img.shape, f"{images[0].shape} (the first frame's)")
        if bayer is not None and (img.shape[0] % 2 or img.shape[1] % 2):
            raise _fail(fpath, "shape", img.shape, "even height and width for a Bayer mosaic")
        images.append(img)
        del i
    extra = {
        k: v for k, v in m.items() if k not in ("version", "frames", "bayer", "optics", "stage")
    }
    return Burst(
        frames=np.stack(images), infos=infos, bayer=bayer, optics=optics, stage=stage, extra=extra
    )


def write_burst(
    path: str | Path,
    frames: Sequence[NDArray[Any]] | NDArray[Any],
    *,
    infos: Sequence[dict[str, Any]] | None = None,
    bayer: str | None = None,
    optics: dict[str, float] | None = None,
    stage: dict[str, float] | None = None,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write a burst directory; the manifest goes last, atomically (write then rename).

    Parameters
    ----------
    path
        Directory to create (may exist).
    frames
        2-D uint16 frames of one size.
    infos
        Optional per-frame fields (``stage_mm``, ``caliper_mm``, ``frame``,
        ``timestamp_ns``); ``file`` is filled in.
    bayer, optics, stage, extra
        Optional top-level fields.
    """
    root = Path(path)
    if infos is not None and len(infos) != len(frames):
        raise ValueError(f"len(infos)={len(infos)}; allowed: {len(frames)} (one per frame)")
    if bayer is not None and bayer not in BAYER_PATTERNS:
        raise ValueError(f"bayer={bayer!r}; allowed: None or one of {', '.join(BAYER_PATTERNS)}")
    (root / "frames").mkdir(parents=True, exist_ok=True)
    entries = []
    shape = None
    for i, f in enumerate(frames):
        a = np.asarray(f)
        if a.dtype != np.uint16 or a.ndim != 2:
            raise ValueError(f"frames[{i}]: dtype={a.dtype}, ndim={a.ndim}; allowed: uint16, 2-D")
        if shape is not None and a.shape != shape:
            raise ValueError(f"frames[{i}].shape={a.shape}; allowed: {shape}")
        shape = a.shape
        name = f"frames/{i:04d}.tif"
        tifffile.imwrite(root / name, a)
        entry = dict(infos[i]) if infos is not None else {}
        entry["file"] = name
        entries.append(entry)
    manifest: dict[str, Any] = dict(extra or {})
    manifest.update({"version": VERSION, "frames": entries, "bayer": bayer})
    if optics:
        manifest["optics"] = dict(optics)
    if stage:
        manifest["stage"] = dict(stage)
    tmp = root / (MANIFEST + ".tmp")
    tmp.write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n")
    os.replace(tmp, root / MANIFEST)
    return root
