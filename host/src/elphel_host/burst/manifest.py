"""A burst's ``manifest.json`` (version 1): its frozen types, its reader and its writer.

``manifest.json`` is ``{"version": 1, "frames": [{"file": "frames/0000.tif", ...}, ...]}``;
each frame entry may carry ``stage_mm``, ``caliper_mm``, ``frame`` and ``timestamp_ns``
(and ``index``, its place in the plan, when a capture wrote it); the top level may carry
``optics`` (``focal_length_mm``, ``pixel_pitch_um``, ``object_distance_mm``), ``stage``
(``mm_per_step``, ``axis_angle_deg``) and ``bayer`` (``"RGGB"``, ``"GRBG"``, ``"GBRG"``,
``"BGGR"`` or null). Other keys, at the top and in frame entries, are kept as they are.

Here are :class:`Manifest` / :class:`FrameEntry` (frozen, ``from_json``/``to_json``) and
:func:`read_manifest` / :func:`write_manifest` (a capture rewrites it after each frame,
through :mod:`elphel_host.fileio`). The burst directory as a whole (the manifest and its
frame files) is read and written by :mod:`elphel_host.burst.io`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from elphel_host import strict_json
from elphel_host.errors import InputFormatError
from elphel_host.fileio import write_atomic
from elphel_host.limits import HostLimits

BAYER_PATTERNS = ("RGGB", "GRBG", "GBRG", "BGGR")
MANIFEST = "manifest.json"
VERSION = 1

_FRAME_NUMBERS: dict[str, type] = {"stage_mm": float, "caliper_mm": float, "frame": int}
_FRAME_NUMBERS["timestamp_ns"] = int
OPTICS = ("focal_length_mm", "pixel_pitch_um", "object_distance_mm")
_STAGE = ("mm_per_step", "axis_angle_deg")
_POSITIVE = ("focal_length_mm", "pixel_pitch_um", "object_distance_mm", "mm_per_step")
_TOP = ("version", "frames", "bayer", "optics", "stage")
_ENTRY_KEYS = ("file", "index", *_FRAME_NUMBERS)


def _is_int(v: Any) -> bool:
    return isinstance(v, int | np.integer) and not isinstance(v, bool)


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float | np.number) and not isinstance(v, bool) and math.isfinite(v)


def check_bayer(bayer: Any) -> str | None:
    """``bayer`` if it is None or a 2x2 pattern name; else ValueError naming it."""
    if bayer is not None and bayer not in BAYER_PATTERNS:
        raise ValueError(f"bayer={bayer!r}; allowed: null or one of {', '.join(BAYER_PATTERNS)}")
    return bayer


def _number_map(name: str, obj: Any, keys: Sequence[str]) -> dict[str, float]:
    if obj is None:
        return {}
    if not isinstance(obj, Mapping):
        raise ValueError(f"{name}={obj!r}; allowed: an object")
    out: dict[str, float] = {}
    for k, v in obj.items():
        if k not in keys:
            raise ValueError(f"{name}.{k}={v!r}; allowed: keys {', '.join(keys)}")
        if not _is_number(v):
            raise ValueError(f"{name}.{k}={v!r}; allowed: a finite number")
        out[k] = float(v)
    for k in _POSITIVE:
        if k in out and out[k] <= 0:
            raise ValueError(f"{name}.{k}={out[k]!r}; allowed: > 0")
    return out


@dataclass(frozen=True)
class FrameEntry:
    """One frame of a manifest: its file and what was recorded when it was taken."""

    file: str
    stage_mm: float | None = None
    caliper_mm: float | None = None
    frame: int | None = None
    timestamp_ns: int | None = None
    index: int | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.file, str) or not self.file:
            raise ValueError(
                f"file={self.file!r}; allowed: a relative path such as frames/0000.tif"
            )
        if Path(self.file).is_absolute() or ".." in Path(self.file).parts:
            raise ValueError(f"file={self.file!r}; allowed: a path inside the burst directory")

    @property
    def position_mm(self) -> float | None:
        """Where the carriage was: the caliper's reading, else the commanded position."""
        return self.caliper_mm if self.caliper_mm is not None else self.stage_mm

    @classmethod
    def from_json(cls, obj: Any, *, where: str = "frame") -> FrameEntry:
        """A frame entry from its JSON object.

        Raises
        ------
        ValueError
            Naming the field (``where`` first, e.g. ``frames[3]``) and what is allowed.
        """
        if not isinstance(obj, Mapping):
            raise ValueError(f'{where}={obj!r}; allowed: an object with "file"')
        kw: dict[str, Any] = {}
        for k, typ in (*_FRAME_NUMBERS.items(), ("index", int)):
            v = obj.get(k)
            if v is None:
                continue
            if not (_is_int(v) if typ is int else _is_number(v)):
                allowed = "an integer" if typ is int else "a number"
                raise ValueError(f"{where}.{k}={v!r}; allowed: {allowed}")
            kw[k] = typ(v)
        try:
            return cls(file=obj.get("file"), **kw, extra=_rest(obj, _ENTRY_KEYS))  # type: ignore[arg-type]
        except ValueError as e:
            raise ValueError(f"{where}.{e}") from e

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = dict(self.extra)
        d["file"] = self.file
        for k in ("index", *_FRAME_NUMBERS):
            v = getattr(self, k)
            if v is not None:
                d[k] = v
        return d


def _rest(obj: Mapping[str, Any], known: Sequence[str]) -> dict[str, Any]:
    return {k: v for k, v in obj.items() if k not in known}


@dataclass(frozen=True)
class Manifest:
    """A burst's ``manifest.json``.

    Attributes
    ----------
    frames
        The frame entries (a capture keeps them in plan order, by ``index``).
    bayer
        Bayer pattern or None (mono).
    optics, stage
        The optional top-level objects (empty when absent).
    extra
        Other top-level keys, kept as they were (a capture's ``plan`` and ``capture``).
    """

    frames: tuple[FrameEntry, ...] = ()
    bayer: str | None = None
    optics: Mapping[str, float] = field(default_factory=dict)
    stage: Mapping[str, float] = field(default_factory=dict)
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        check_bayer(self.bayer)
        object.__setattr__(self, "optics", _number_map("optics", self.optics, OPTICS))
        object.__setattr__(self, "stage", _number_map("stage", self.stage, _STAGE))

    @classmethod
    def from_json(cls, obj: Any) -> Manifest:
        """A manifest from its JSON object; ValueError names the field and what is allowed."""
        if not isinstance(obj, Mapping):
            raise ValueError(f"top level={type(obj).__name__!r}; allowed: an object")
        if obj.get("version") != VERSION:
            raise ValueError(f"version={obj.get('version')!r}; allowed: {VERSION}")
        entries = obj.get("frames")
        if not isinstance(entries, list):
            raise ValueError(f"frames={entries!r}; allowed: a list of frame objects")
        frames = [FrameEntry.from_json(e, where=f"frames[{i}]") for i, e in enumerate(entries)]
        return cls(
            frames=tuple(frames),
            bayer=obj.get("bayer"),
            optics=obj.get("optics"),  # type: ignore[arg-type]  # checked by __post_init__
            stage=obj.get("stage"),  # type: ignore[arg-type]
            extra=_rest(obj, _TOP),
        )

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = dict(self.extra)
        d.update({"version": VERSION, "frames": [e.to_json() for e in self.frames]})
        d["bayer"] = self.bayer
        if self.optics:
            d["optics"] = dict(self.optics)
        if self.stage:
            d["stage"] = dict(self.stage)
        return d

    def entry(self, index: int) -> FrameEntry:
        """The entry a capture recorded for plan position ``index``."""
        for e in self.frames:
            if e.index == index:
                return e
        known = sorted(e.index for e in self.frames if e.index is not None)
        raise KeyError(f"index={index}; allowed: one of {known}")

    def with_frame(self, entry: FrameEntry) -> Manifest:
        """A copy with ``entry`` added, the frames kept in ``index`` order."""
        frames = sorted((*self.frames, entry), key=lambda e: -1 if e.index is None else e.index)
        return replace(self, frames=tuple(frames))

    def stage_prior_px(self) -> list[tuple[float, float]] | None:
        """Per-frame image shift (dy, dx) in px predicted from stage and optics, if known.

        The camera moving by ``d`` mm along the stage axis (angle ``axis_angle_deg`` from
        the sensor's x axis) shifts the image of the object plane by
        ``d * f / (Z - f) / pitch`` px along the same direction. None when the optics or
        any frame's position is missing.
        """
        f = self.optics.get("focal_length_mm")
        p = self.optics.get("pixel_pitch_um")
        z = self.optics.get("object_distance_mm")
        if f is None or p is None or z is None or z <= f:
            return None
        pos: list[float] = []
        for entry in self.frames:
            v = entry.position_mm
            if v is None:
                return None
            pos.append(v)
        px_per_mm = f / (z - f) * 1000.0 / p
        theta = math.radians(self.stage.get("axis_angle_deg", 0.0))
        p0 = pos[0]
        return [
            ((v - p0) * px_per_mm * math.sin(theta), (v - p0) * px_per_mm * math.cos(theta))
            for v in pos
        ]


def read_manifest(directory: str | Path) -> Manifest | None:
    """The manifest of a burst directory, or None if it has none (yet).

    Raises
    ------
    InputFormatError
        Naming the file, the field, the value and what is allowed.
    """
    path = Path(directory) / MANIFEST
    if not path.is_file():
        return None
    limits = HostLimits.from_env()
    size = path.stat().st_size
    if size > limits.json_bytes:
        raise InputFormatError(
            f"{path}: {size} bytes; limit json_bytes = {limits.json_bytes} "
            "(raise ELPHEL_LIMIT_JSON_BYTES)"
        )
    try:
        obj = strict_json.loads(path.read_bytes(), what=str(path), limit_bytes=limits.json_bytes)
    except ValueError as e:
        raise InputFormatError(str(e)) from e
    entries = obj.get("frames") if isinstance(obj, dict) else None
    if isinstance(entries, list) and len(entries) > limits.manifest_frames:
        raise InputFormatError(
            f"{path}: {len(entries)} frames; limit manifest_frames = {limits.manifest_frames} "
            "(raise ELPHEL_LIMIT_MANIFEST_FRAMES)"
        )
    try:
        return Manifest.from_json(obj)
    except ValueError as e:
        raise InputFormatError(f"{path}: {e}") from e


def write_manifest(directory: str | Path, manifest: Manifest, *, sync: bool = False) -> Path:
    """Write ``directory/manifest.json`` atomically (``sync``: on disk before the rename).

    Strict JSON: a NaN or infinite value raises `DeviceAnswerError` and nothing is written.
    """
    what = str(Path(directory) / MANIFEST)
    text = strict_json.dumps(manifest.to_json(), what=what, indent=1, sort_keys=True) + "\n"
    return write_atomic(Path(directory) / MANIFEST, text.encode(), sync=sync)
