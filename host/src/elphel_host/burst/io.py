"""The burst format: ``manifest.json`` version 1 + ``frames/NNNN.tif``, one owner.

Layout::

    BURST/manifest.json
    BURST/frames/0000.tif ...   16-bit, one frame each (Bayer raw or mono)

``manifest.json`` is ``{"version": 1, "frames": [{"file": "frames/0000.tif", ...}, ...]}``;
each frame entry may carry ``stage_mm``, ``caliper_mm``, ``frame`` and ``timestamp_ns``
(and ``index``, its place in the plan, when a capture wrote it); the top level may carry
``optics`` (``focal_length_mm``, ``pixel_pitch_um``, ``object_distance_mm``), ``stage``
(``mm_per_step``, ``axis_angle_deg``) and ``bayer`` (``"RGGB"``, ``"GRBG"``, ``"GBRG"``,
``"BGGR"`` or null). Other keys, at the top and in frame entries, are kept as they are.

Here are :class:`Manifest` / :class:`FrameEntry` (frozen, ``from_json``/``to_json``),
:func:`read_burst` / :func:`write_burst` (directories), :func:`read_manifest` /
:func:`write_manifest` (a capture rewrites it after each frame, through
:mod:`elphel_host.fileio`) and :func:`read_frame`. The plan file is in ``burst/plan.py``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
from numpy.typing import NDArray

from elphel_host.errors import InputFormatError
from elphel_host.fileio import write_atomic
from elphel_host.tp.io import MANIFEST as QUAD_MANIFEST
from elphel_host.tp.io import QuadCamera, QuadManifest

BAYER_PATTERNS = ("RGGB", "GRBG", "GBRG", "BGGR")
MANIFEST = "manifest.json"
VERSION = 1

_FRAME_NUMBERS: dict[str, type] = {"stage_mm": float, "caliper_mm": float, "frame": int}
_FRAME_NUMBERS["timestamp_ns"] = int
_OPTICS = ("focal_length_mm", "pixel_pitch_um", "object_distance_mm")
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


# Older name of FrameEntry (before the burst format had one owner), kept for scripts.
FrameInfo = FrameEntry


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
        object.__setattr__(self, "optics", _number_map("optics", self.optics, _OPTICS))
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


def _fail(path: Path, what: str, value: Any, allowed: str) -> InputFormatError:
    return InputFormatError(f"{path}: {what}={value!r}; allowed: {allowed}")


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
    try:
        obj = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputFormatError(f"{path}: not valid JSON ({e})") from e
    try:
        return Manifest.from_json(obj)
    except ValueError as e:
        raise InputFormatError(f"{path}: {e}") from e


def write_manifest(directory: str | Path, manifest: Manifest, *, sync: bool = False) -> Path:
    """Write ``directory/manifest.json`` atomically (``sync``: on disk before the rename)."""
    text = json.dumps(manifest.to_json(), indent=1, sort_keys=True) + "\n"
    return write_atomic(Path(directory) / MANIFEST, text.encode(), sync=sync)


def read_frame(
    path: str | Path, *, bayer: str | None, like: tuple[tuple[int, ...], str] | None = None
) -> NDArray[np.uint16]:
    """One frame file, checked: a 2-D uint16 TIFF (even-sized for a Bayer mosaic).

    ``like`` is (shape, file name) of a frame already read: this one must have its shape.
    """
    path = Path(path)
    try:
        img = tifffile.imread(path)
    except Exception as e:  # tifffile raises many kinds on a damaged file
        raise InputFormatError(f"{path}: not a readable TIFF ({e})") from e
    if img.dtype != np.uint16:
        raise _fail(path, "dtype", str(img.dtype), "uint16")
    if img.ndim != 2:
        raise _fail(path, "shape", img.shape, "a 2-D (single-channel) image")
    if like is not None and img.shape != like[0]:
        raise _fail(path, "shape", img.shape, f"{like[0]} (the shape of {like[1]})")
    if bayer is not None and (img.shape[0] % 2 or img.shape[1] % 2):
        raise _fail(path, "shape", img.shape, "even height and width for a Bayer mosaic")
    return np.asarray(img, dtype=np.uint16)


@dataclass(frozen=True)
class Burst:
    """A burst directory as loaded: the (N, H, W) uint16 frames and their manifest.

    ``infos`` (the frame entries), ``bayer``, ``optics``, ``stage`` and ``extra`` are the
    manifest's, at hand.
    """

    frames: NDArray[np.uint16]
    manifest: Manifest

    infos = property(lambda self: self.manifest.frames)
    bayer = property(lambda self: self.manifest.bayer)
    optics = property(lambda self: self.manifest.optics)
    stage = property(lambda self: self.manifest.stage)
    extra = property(lambda self: self.manifest.extra)

    def stage_prior_px(self) -> list[tuple[float, float]] | None:
        """See :meth:`Manifest.stage_prior_px`."""
        return self.manifest.stage_prior_px()


def read_burst(path: str | Path) -> Burst:
    """Load and validate a burst directory.

    Raises
    ------
    InputFormatError
        Naming the file, the field, the value and what is allowed, when the directory
        does not follow the burst format.
    """
    root = Path(path)
    mpath = root / MANIFEST
    manifest = read_manifest(root)
    if manifest is None:
        raise InputFormatError(f"{root}: no {MANIFEST} (expected a burst directory)")
    if not manifest.frames:
        raise _fail(mpath, "frames", [], "a non-empty list of frame objects")
    for i, entry in enumerate(manifest.frames):
        if not (root / entry.file).is_file():
            raise InputFormatError(
                f"{mpath}: frames[{i}].file={entry.file!r} does not exist in {root}"
            )
    images: list[NDArray[np.uint16]] = []
    for entry in manifest.frames:
        like = None if not images else (images[0].shape, manifest.frames[0].file)
        images.append(read_frame(root / entry.file, bayer=manifest.bayer, like=like))
    return Burst(frames=np.stack(images), manifest=manifest)


def write_burst(
    path: str | Path,
    frames: Sequence[NDArray[Any]] | NDArray[Any],
    *,
    infos: Sequence[Mapping[str, Any]] | None = None,
    bayer: str | None = None,
    optics: Mapping[str, float] | None = None,
    stage: Mapping[str, float] | None = None,
    extra: Mapping[str, Any] | None = None,
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
    check_bayer(bayer)
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
        entry = {**(infos[i] if infos is not None else {}), "file": name}
        entries.append(FrameEntry.from_json(entry, where=f"infos[{i}]"))
    manifest = Manifest(
        tuple(entries), bayer, optics=optics or {}, stage=stage or {}, extra=extra or {}
    )
    write_manifest(root, manifest)
    return root


# --- Quad bursts -------------------------------------------------------------------------
#
#     QB/quad.json          a quad manifest whose cameras' "file" name burst directories
#     QB/cam0/ .. QB/cam3/  burst directories; frame k of every camera is one trigger


def quad_burst_cameras(positions: Sequence[tuple[float, float]]) -> tuple[QuadCamera, ...]:
    """Cameras 0..3 of a quad burst: ``file`` = ``cam0`` .. ``cam3`` (burst directories)."""
    return tuple(
        QuadCamera(file=f"cam{i}", position=(float(p[0]), float(p[1])))
        for i, p in enumerate(positions)
    )


@dataclass(frozen=True)
class QuadBurst:
    """A quad-burst directory as loaded: quad.json and each camera's burst.

    Attributes
    ----------
    manifest
        The ``quad.json``.
    bursts
        Camera i's burst (frames ``(N, H, W)``), N and the frame size the same for all.
    """

    manifest: QuadManifest
    bursts: tuple[Burst, ...]

    @property
    def frames(self) -> int:
        return int(self.bursts[0].frames.shape[0])


def read_quad_burst(path: str | Path) -> QuadBurst:
    """Load a quad-burst directory and check that its four bursts belong together.

    Raises
    ------
    InputFormatError
        When quad.json or a camera's burst directory is missing or malformed, when the
        bursts differ in frame count, size or Bayer pattern, or when frame k of two
        cameras carries different ``timestamp_ns`` (not one trigger).
    """
    root = Path(path)
    manifest = QuadManifest.read(root)
    source = root / QUAD_MANIFEST
    bursts = []
    for i, cam in enumerate(manifest.cameras):
        d = root / cam.file
        if not d.is_dir():
            raise InputFormatError(
                f"{source}: cameras[{i}].file={cam.file!r} is not a burst directory in {root}"
            )
        bursts.append(read_burst(d))
    counts = [b.frames.shape[0] for b in bursts]
    if len(set(counts)) != 1:
        raise InputFormatError(f"{root}: the cameras' bursts differ in frame count: {counts}")
    shapes = [b.frames.shape[1:] for b in bursts]
    if len(set(shapes)) != 1:
        raise InputFormatError(f"{root}: the cameras' frames differ in size: {shapes}")
    patterns = {b.bayer for b in bursts} | {manifest.bayer}
    if len(patterns) != 1:
        raise InputFormatError(
            f"{root}: Bayer patterns differ between quad.json and the bursts: "
            f"{sorted(map(str, patterns))}"
        )
    for k in range(counts[0]):
        stamps = [b.infos[k].timestamp_ns for b in bursts]
        if None not in stamps and len(set(stamps)) != 1:
            raise InputFormatError(
                f"{root}: frame {k} is not of one trigger: timestamp_ns {stamps} (cam0..cam3)"
            )
    return QuadBurst(manifest=manifest, bursts=tuple(bursts))


def write_quad_burst(
    path: str | Path,
    frames: NDArray[Any],
    *,
    positions: Sequence[tuple[float, float]],
    infos: Sequence[Mapping[str, Any]] | None = None,
    bayer: str | None = None,
    optics: Mapping[str, float] | None = None,
    stage: Mapping[str, float] | None = None,
    full_scale_dn: float | None = None,
    extra: Mapping[str, Any] | None = None,
) -> Path:
    """Write a quad-burst directory from frames ``(4, N, H, W)`` uint16; quad.json goes last.

    ``infos`` (one per frame k, shared by the four cameras), ``bayer``, ``stage`` go into
    every camera's manifest; ``optics`` into quad.json (``focal_length_mm``,
    ``pixel_pitch_um``, ``baseline_mm``) and the bursts' manifests.
    """
    a = np.asarray(frames)
    if a.ndim != 4 or a.shape[0] != 4:
        raise ValueError(f"frames must have shape (4, N, H, W), got {a.shape}")
    root = Path(path)
    root.mkdir(parents=True, exist_ok=True)
    cams = quad_burst_cameras(positions)
    burst_optics = {k: v for k, v in (optics or {}).items() if k in _OPTICS}
    for i, cam in enumerate(cams):
        write_burst(
            root / cam.file, list(a[i]), infos=infos, bayer=bayer, optics=burst_optics,
            stage=stage, extra={"quad_camera": i},
        )  # fmt: skip
    manifest = QuadManifest(
        cameras=cams,
        bayer=bayer,
        full_scale_dn=full_scale_dn,
        optics=dict(optics) if optics else None,
        extra=dict(extra or {}),
    )
    manifest.write(root)
    return root
