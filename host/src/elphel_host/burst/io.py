"""The burst directory: ``manifest.json`` + ``frames/NNNN.tif``, and the quad burst of four.

Layout::

    BURST/manifest.json
    BURST/frames/0000.tif ...   16-bit, one frame each (Bayer raw or mono)

The manifest (its fields, :class:`~elphel_host.burst.manifest.Manifest` and its reader and
writer) is in ``burst/manifest.py``. Here are :func:`read_burst` / :func:`write_burst`
(directories), :func:`read_frame`, and :func:`read_quad_burst` / :func:`write_quad_burst`
(quad-burst directories). The plan file is in ``burst/plan.py``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
from numpy.typing import NDArray

from elphel_host.burst.manifest import (
    MANIFEST,
    OPTICS,
    FrameEntry,
    Manifest,
    check_bayer,
    read_manifest,
    write_manifest,
)
from elphel_host.confined import inside
from elphel_host.errors import InputFormatError
from elphel_host.tp.io import MANIFEST as QUAD_MANIFEST
from elphel_host.tp.io import QuadCamera, QuadManifest


def _fail(path: Path, what: str, value: Any, allowed: str) -> InputFormatError:
    return InputFormatError(f"{path}: {what}={value!r}; allowed: {allowed}")


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
    manifest = read_manifest(root)
    if manifest is None:
        raise InputFormatError(f"{root}: no {MANIFEST} (expected a burst directory)")
    files = _frame_files(root, manifest)
    images: list[NDArray[np.uint16]] = []
    for file in files:
        like = None if not images else (images[0].shape, manifest.frames[0].file)
        images.append(read_frame(file, bayer=manifest.bayer, like=like))
    return Burst(frames=np.stack(images), manifest=manifest)


def _frame_files(root: Path, manifest: Manifest) -> list[Path]:
    """The frames' files, checked before any is read: present, distinct, inside ``root``."""
    mpath = root / MANIFEST
    if not manifest.frames:
        raise _fail(mpath, "frames", [], "a non-empty list of frame objects")
    files = []
    for i, entry in enumerate(manifest.frames):
        file = inside(root, entry.file, where=f"{mpath}: frames[{i}].file")
        if not file.is_file():
            raise InputFormatError(
                f"{mpath}: frames[{i}].file={entry.file!r} does not exist in {root}"
            )
        files.append(file)
    distinct = len({f.resolve() for f in files})
    if distinct != len(files):
        raise InputFormatError(
            f"{mpath}: {len(files)} frames name only {distinct} distinct files; "
            "allowed: one file per frame"
        )
    return files


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
        d = manifest.file_of(root, i)
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
    burst_optics = {k: v for k, v in (optics or {}).items() if k in OPTICS}
    for i, cam in enumerate(cams):
        write_burst(
            root / cam.file,
            list(a[i]),
            infos=infos,
            bayer=bayer,
            optics=burst_optics,
            stage=stage,
            extra={"quad_camera": i},
        )
    manifest = QuadManifest(
        cameras=cams,
        bayer=bayer,
        full_scale_dn=full_scale_dn,
        optics=dict(optics) if optics else None,
        extra=dict(extra or {}),
    )
    manifest.write(root)
    return root
