"""A views directory (docs/calibration.md) read and searched for the board.

One camera: image files in the directory, one view each (16-bit TIFF as captured, Bayer
frames included when the TIFF's metadata names ``bayer``; PNG; JPEG). A quad: one quad
directory (quad.json and its four images) per view, as subdirectories. Views are taken
in name order.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import tifffile
from numpy.typing import NDArray

from elphel_host.calibrate.detect import detect
from elphel_host.calibrate.observations import CalibrationInputError, Observations
from elphel_host.calibrate.pattern import Checkerboard
from elphel_host.errors import InputFormatError
from elphel_host.tp.io import MANIFEST, read_quad_dir

IMAGE_SUFFIXES = (".tif", ".tiff", ".png", ".jpg", ".jpeg")
Progress = Callable[[int, int], None]


def _read_image(path: Path) -> tuple[NDArray[np.generic], str | None]:
    """An image and its Bayer pattern (from a TIFF's JSON metadata; None otherwise)."""
    if path.suffix.lower() in (".tif", ".tiff"):
        with tifffile.TiffFile(path) as tif:
            image = tif.asarray()
            first = tif.pages.first if tif.pages else None
            desc = getattr(first, "description", "") or ""
        try:
            meta = json.loads(desc) if desc else {}
        except json.JSONDecodeError:
            meta = {}
        bayer = meta.get("bayer") if isinstance(meta, dict) else None
        return image, bayer if isinstance(bayer, str) else None
    read = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if read is None:
        raise InputFormatError(f"{path}: not a readable image; allowed: TIFF, PNG, JPEG")
    return np.asarray(read), None


def view_sources(root: Path) -> tuple[list[Path], bool]:
    """The views (paths) of a views directory and whether they are quad directories."""
    if not root.is_dir():
        raise InputFormatError(
            f"{root}: not a directory; allowed: a views directory of image files, or of quad "
            "directories (docs/calibration.md)"
        )
    quads = sorted(p for p in root.iterdir() if (p / MANIFEST).is_file())
    if quads:
        return quads, True
    files = sorted(p for p in root.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise InputFormatError(
            f"{root}: no image files ({', '.join(IMAGE_SUFFIXES)}) and no quad directories"
        )
    return files, False


def view_images(path: Path, *, quad: bool) -> tuple[list[NDArray[np.generic]], str | None]:
    """The images of one view (a quad directory's four, or one file's) and their Bayer pattern."""
    if quad:
        qs = read_quad_dir(path)
        return list(qs.quad.images), qs.manifest.bayer
    image, bayer = _read_image(path)
    return [image], bayer


def read_views(
    root: str | Path, pattern: Checkerboard, *, progress: Progress | None = None
) -> Observations:
    """Detect the board in every image of a views directory.

    Raises
    ------
    CalibrationInputError
        When the board is found in no image (the message says how to count corners).
    InputFormatError
        When an image cannot be read or the images of one camera differ in size.
    """
    sources, quad = view_sources(Path(root))
    rows, sizes = [], None
    for k, path in enumerate(sources):
        images, bayer = view_images(path, quad=quad)
        shapes = tuple((int(im.shape[1]), int(im.shape[0])) for im in images)
        if sizes is None:
            sizes = shapes
        elif shapes != sizes:
            raise InputFormatError(
                f"{path}: image sizes {shapes}; allowed: {sizes} as the first view"
            )
        rows.append(tuple(detect(np.asarray(im), pattern, bayer=bayer) for im in images))
        if progress is not None:
            progress(k + 1, len(sources))
    assert sizes is not None
    if not any(found is not None for row in rows for found in row):
        raise CalibrationInputError(
            f"{root}: the board {pattern.spec} was found in none of {len(rows)} view(s): check "
            "--pattern (COLSxROWS counts inner corners: a board of 10 x 7 squares is 9x6) and "
            "that the whole board, with a white margin, is in the images"
        )
    return Observations(pattern, sizes, tuple(rows), tuple(p.name for p in sources))
