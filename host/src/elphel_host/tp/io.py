"""The quad directory format: its one reader and writer.

A quad directory (docs/tile-processor.md, Files) is ``quad.json`` + four same-size 16-bit images
``cam0.tif .. cam3.tif`` of one instant; in a quad-burst directory each
camera's ``file`` names its burst directory instead. ``quad.json`` is one frozen
:class:`QuadManifest`: whoever writes or reads one (`elphel tp capture`, `elphel tp`, the
simulator) goes through :meth:`QuadManifest.to_json` / :meth:`QuadManifest.from_json`.

The DSI and ML_DATA files live in :mod:`elphel_host.tp.dsi`; their functions are
importable from here too. The ``kernels`` entry and its array are
:mod:`elphel_host.tp.kernel_file`'s; the ``calibration`` entry names a calibration.json
inside the directory (:mod:`elphel_host.tp.calibrated`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import tifffile
from numpy.typing import NDArray

from elphel_host import strict_json
from elphel_host.confined import check_relative, inside
from elphel_host.errors import InputFormatError
from elphel_host.fileio import replacing, write_atomic
from elphel_host.tp.bayer import BAYER_PATTERNS
from elphel_host.tp.calibrated import CALIBRATION_FILE, CalibratedGeometry, read_calibration
from elphel_host.tp.dsi import DAMAGED_TIFF_ERRORS
from elphel_host.tp.geometry import QuadGeometry
from elphel_host.tp.images import QuadImages
from elphel_host.tp.kernel_file import KernelFile, kernel_file, load_kernels

F32 = NDArray[np.float32]

MANIFEST = "quad.json"


def camera_list(doc: Any, where: str) -> list[Any]:
    """``doc["cameras"]``, which must list four cameras."""
    cams = doc.get("cameras") if isinstance(doc, dict) else None
    if not isinstance(cams, list) or len(cams) != 4:
        raise InputFormatError(f"{where}: 'cameras' must list 4 cameras, got {cams!r}")
    return cams


# A position is in units of the square's side: a camera 100 sides away is no quad.
POSITION_MAX = 100.0
# Full scale of the images: 8..32-bit integer data, or float data scaled to 1.
FULL_SCALE_RANGE = (1e-3, 2.0**32)


def parse_position(value: Any, where: str) -> tuple[float, float]:
    """A camera ``position``: ``[x, y]`` finite numbers in units of the square's side."""
    if not (
        isinstance(value, list)
        and len(value) == 2
        and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
        and all(math.isfinite(v) and abs(v) <= POSITION_MAX for v in value)
    ):
        raise InputFormatError(
            f"{where}.position={value!r}; allowed: [x, y] finite numbers within +-{POSITION_MAX:g}"
        )
    return float(value[0]), float(value[1])


def check_full_scale(full: Any, source: str) -> None:
    """``full_scale_dn``: None or a finite number in `FULL_SCALE_RANGE`."""
    lo, hi = FULL_SCALE_RANGE
    if full is not None and not (
        isinstance(full, int | float) and not isinstance(full, bool) and lo <= full <= hi
    ):
        raise InputFormatError(
            f"{source}: full_scale_dn={full!r}; allowed: a number in {lo:g}..{hi:.0f}"
        )


@dataclass(frozen=True)
class QuadCamera:
    """One camera of ``quad.json``.

    Attributes
    ----------
    file
        Its image (or, in a quad burst, its burst directory), relative to the directory.
    position
        Camera centre in units of the square's side, +x right, +y down.
    fields
        Everything else the entry records, in order (a capture writes ``port``,
        ``sensor``, ``frame``, ``timestamp_ns`` and ``params``).
    """

    file: str
    position: tuple[float, float]
    fields: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        clash = {"file", "position"} & set(self.fields)
        if clash:
            raise ValueError(f"fields {sorted(clash)} are attributes of QuadCamera, not fields")

    def to_json(self) -> dict[str, Any]:
        """The camera's entry of ``quad.json``."""
        return {"file": self.file, "position": list(self.position), **self.fields}


def _check_distinct(cameras: Sequence[QuadCamera], source: str) -> None:
    """Four different files at four different positions."""
    positions = [cam.position for cam in cameras]
    if len(set(positions)) != len(positions):
        raise InputFormatError(
            f"{source}: cameras' positions {positions}; allowed: four distinct positions"
        )
    files = [cam.file for cam in cameras]
    if len(set(files)) != len(files):
        raise InputFormatError(f"{source}: cameras' files {files}; allowed: four distinct files")


def quad_cameras(
    positions: Sequence[tuple[float, float]],
    fields: Sequence[Mapping[str, Any]] | None = None,
) -> tuple[QuadCamera, ...]:
    """Cameras 0..3 with the standard file names ``cam0.tif .. cam3.tif``."""
    per_camera = [{}] * len(positions) if fields is None else list(fields)
    return tuple(
        QuadCamera(file=f"cam{i}.tif", position=(float(p[0]), float(p[1])), fields=dict(f))
        for i, (p, f) in enumerate(zip(positions, per_camera, strict=True))
    )


@dataclass(frozen=True)
class QuadManifest:
    """``quad.json``: the cameras, their positions, the Bayer pattern and optional records.

    Attributes
    ----------
    cameras
        Cameras 0..3.
    bayer
        ``None`` (mono) or one of ``GRBG``, ``RGGB``, ``GBRG``, ``BGGR``.
    full_scale_dn
        The images' full scale (e.g. 4095 for 12-bit data); None: from the data.
    optics
        ``focal_length_mm``, ``pixel_pitch_um``, ``baseline_mm`` (the square's side), ...
    kernels
        Aberration-correction kernels, if any.
    calibration
        The quad's calibration.json (or its directory), relative to the quad directory;
        with it the images are the cameras' raw images (docs/tile-processor.md).
    extra
        Other top-level records, kept in order (a capture writes ``capture``).
    """

    VERSION: ClassVar[int] = 1
    FIELDS: ClassVar[tuple[str, ...]] = (
        "version",
        "cameras",
        "bayer",
        "full_scale_dn",
        "optics",
        "kernels",
        "calibration",
    )

    cameras: tuple[QuadCamera, ...]
    bayer: str | None = None
    full_scale_dn: int | float | None = None
    optics: Mapping[str, Any] | None = None
    kernels: KernelFile | None = None
    calibration: str | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if len(self.cameras) != 4:
            raise ValueError(f"cameras: {len(self.cameras)} given; allowed: 4")
        if self.bayer is not None and self.bayer not in BAYER_PATTERNS:
            raise ValueError(
                f"bayer={self.bayer!r}; allowed: None or one of {', '.join(BAYER_PATTERNS)}"
            )
        clash = set(self.FIELDS) & set(self.extra)
        if clash:
            raise ValueError(f"extra {sorted(clash)} are attributes of QuadManifest, not extras")

    @property
    def positions(self) -> tuple[tuple[float, float], ...]:
        """The four camera positions."""
        return tuple(cam.position for cam in self.cameras)

    @property
    def geometry(self) -> QuadGeometry:
        """The quad's geometry (positions and the six pairs)."""
        return QuadGeometry(positions=self.positions)

    def to_json(self) -> dict[str, Any]:
        """The ``quad.json`` document."""
        doc: dict[str, Any] = {
            "version": self.VERSION,
            "cameras": [cam.to_json() for cam in self.cameras],
            "bayer": self.bayer,
        }
        if self.full_scale_dn is not None:
            doc["full_scale_dn"] = self.full_scale_dn
        if self.optics is not None:
            doc["optics"] = dict(self.optics)
        if self.kernels is not None:
            doc["kernels"] = self.kernels.to_json()
        if self.calibration is not None:
            doc["calibration"] = self.calibration
        doc.update(self.extra)
        return doc

    @classmethod
    def from_json(cls, doc: Any, *, source: str = MANIFEST) -> QuadManifest:
        """Check and take a ``quad.json`` document; ``source`` names it in errors.

        Raises
        ------
        InputFormatError
            A field is missing or has a value the format does not allow (the message
            names the field, the value and what is allowed).
        """
        if not isinstance(doc, dict):
            raise InputFormatError(f"{source}: top level must be an object")
        if doc.get("version") != cls.VERSION:
            raise InputFormatError(f"{source}: version={doc.get('version')!r}; allowed: 1")
        cams = camera_list(doc, source)
        bayer = doc.get("bayer")
        if bayer is not None and bayer not in BAYER_PATTERNS:
            raise InputFormatError(
                f"{source}: bayer={bayer!r}; allowed: null or one of {', '.join(BAYER_PATTERNS)}"
            )
        cameras = []
        for i, cam in enumerate(cams):
            if not isinstance(cam, dict) or "file" not in cam or "position" not in cam:
                raise InputFormatError(
                    f"{source}: cameras[{i}] needs 'file' and 'position', got {cam!r}"
                )
            position = parse_position(cam["position"], f"{source}: cameras[{i}]")
            file = check_relative(cam["file"], where=f"{source}: cameras[{i}].file")
            rest = {k: v for k, v in cam.items() if k not in ("file", "position")}
            cameras.append(QuadCamera(file=file, position=position, fields=rest))
        _check_distinct(cameras, source)
        full = doc.get("full_scale_dn")
        check_full_scale(full, source)
        optics = doc.get("optics")
        if optics is not None and not isinstance(optics, dict):
            raise InputFormatError(f"{source}: optics={optics!r}; allowed: an object")
        return cls(
            cameras=tuple(cameras),
            bayer=bayer,
            full_scale_dn=full,
            optics=optics,
            kernels=kernel_file(doc.get("kernels"), source),
            calibration=None
            if doc.get("calibration") is None
            else check_relative(doc["calibration"], where=f"{source}: calibration"),
            extra={k: v for k, v in doc.items() if k not in cls.FIELDS},
        )

    def calibration_of(self, root: Path, *, image_size: tuple[int, int]) -> CalibratedGeometry:
        """The calibration quad.json names, checked to stay in ``root`` and fit ``image_size``.

        Raises
        ------
        InputFormatError
            No calibration named, one outside ``root``, an unreadable one, or one for
            images of another size (the message names both sizes).
        """
        source = root / MANIFEST
        if self.calibration is None:
            raise InputFormatError(f"{source}: no 'calibration'")
        where = f"{source}: calibration"
        path = inside(root, self.calibration, where=where)
        if path.is_dir():  # a calibration directory: its calibration.json
            path = inside(root, f"{self.calibration}/{CALIBRATION_FILE}", where=where)
        cal = read_calibration(path)
        if cal.image_size != image_size:
            raise InputFormatError(
                f"{source}: calibration {path} is for {cal.image_size[0]}x{cal.image_size[1]} "
                f"images, the quad's images are {image_size[0]}x{image_size[1]}; allowed: a "
                "calibration of these cameras at the same image size (WOI)"
            )
        return cal

    def file_of(self, root: Path, index: int) -> Path:
        """Camera ``index``'s file under ``root``, refused if it (or a link) leaves ``root``."""
        where = f"{root / MANIFEST}: cameras[{index}].file"
        return inside(root, self.cameras[index].file, where=where)

    @classmethod
    def read(cls, root: str | Path) -> QuadManifest:
        """Read ``root/quad.json``."""
        path = Path(root) / MANIFEST
        if not path.is_file():
            raise InputFormatError(
                f"{root}: no {MANIFEST} (expected a quad directory: {MANIFEST} + cam0..3.tif)"
            )
        return cls.from_json(strict_json.load_file(path), source=str(path))

    def write(self, root: str | Path) -> Path:
        """Write ``root/quad.json`` (atomically, strict JSON)."""
        text = strict_json.dumps(self.to_json(), what=str(Path(root) / MANIFEST), indent=2) + "\n"
        return write_atomic(Path(root) / MANIFEST, text.encode())


def write_quad_dir(
    root: str | Path,
    manifest: QuadManifest,
    images: Sequence[NDArray[Any] | bytes],
    *,
    kernels: NDArray[np.floating] | None = None,
) -> Path:
    """Write a quad directory into ``root`` (created if needed), ``quad.json`` last.

    Parameters
    ----------
    root
        The directory.
    manifest
        What ``quad.json`` says; the images are written under its cameras' file names.
    images
        Per camera a 2-D array (written as a TIFF) or the bytes of a TIFF as received.
    kernels
        The array of ``manifest.kernels`` (required exactly when the manifest names one).
    """
    out = Path(root)
    if len(images) != len(manifest.cameras):
        raise ValueError(f"{len(images)} images for {len(manifest.cameras)} cameras")
    if (kernels is None) != (manifest.kernels is None):
        raise ValueError("kernels must be given exactly when the manifest names a kernel file")
    out.mkdir(parents=True, exist_ok=True)
    for cam, image in zip(manifest.cameras, images, strict=True):
        if isinstance(image, bytes):
            write_atomic(out / cam.file, image)
        else:
            with replacing(out / cam.file, keep_suffix=True) as tmp:
                tifffile.imwrite(tmp, image)
    if kernels is not None and manifest.kernels is not None:
        np.save(out / manifest.kernels.file, kernels)
    manifest.write(out)
    return out


@dataclass(frozen=True)
class QuadSet:
    """A quad directory as loaded: images scaled to full scale 1 and what quad.json said."""

    quad: QuadImages
    full_scale_dn: float
    manifest: QuadManifest


def read_quad_dir(path: str | Path) -> QuadSet:
    """Load a quad directory: ``quad.json``, the four images and the optional kernels.

    Raises
    ------
    InputFormatError
        When quad.json or an image is missing or does not follow the format.
    """
    root = Path(path)
    manifest = QuadManifest.read(root)
    source = root / MANIFEST
    images = []
    for i in range(len(manifest.cameras)):
        file = manifest.file_of(root, i)
        if not file.is_file():
            raise InputFormatError(f"{source}: cameras[{i}].file {file} does not exist")
        try:
            img = tifffile.imread(file)
        except DAMAGED_TIFF_ERRORS as e:
            raise InputFormatError(
                f"{file}: not a readable TIFF ({e}); allowed: a 16-bit raw frame"
            ) from e
        if img.ndim != 2:
            raise InputFormatError(
                f"{file}: image must be 2-D (one raw frame), got shape {img.shape}"
            )
        images.append(img)
    shapes = {im.shape for im in images}
    if len(shapes) != 1:
        raise InputFormatError(f"{root}: images differ in size: {sorted(shapes)}")
    h, w = images[0].shape
    if h % 8 or w % 8:
        raise InputFormatError(f"{root}: image size {w}x{h}; allowed: multiples of 8")
    full = manifest.full_scale_dn
    if full is None:
        peak = max(float(np.max(im)) for im in images)
        full = (
            float(2 ** max(8, int(np.ceil(np.log2(peak + 1)))) - 1)
            if np.issubdtype(images[0].dtype, np.integer)
            else max(peak, 1.0)
        )
    # one float32 array, filled camera by camera (no stacked or scaled temporaries)
    stack = np.empty((len(images), h, w), dtype=np.float32)
    for im, out in zip(images, stack, strict=True):
        np.divide(im, np.float32(full), out=out, dtype=np.float32)
    kernels = None
    if manifest.kernels is not None:
        kernels = load_kernels(root / manifest.kernels.file, source)
    geometry = manifest.geometry
    if manifest.calibration is not None:
        cal = manifest.calibration_of(root, image_size=(w, h))
        geometry = QuadGeometry(positions=geometry.positions, calibration=cal)
    quad = QuadImages(
        stack,
        bayer=manifest.bayer,
        geometry=geometry,
        kernels=kernels,
        kernel_step=16 if manifest.kernels is None else manifest.kernels.step,
    )
    return QuadSet(quad=quad, full_scale_dn=float(full), manifest=manifest)
