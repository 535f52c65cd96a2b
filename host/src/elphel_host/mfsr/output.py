"""Write a fused image: a TIFF in the input's units and a PNG preview, each atomically.

Each file is written under a temporary name in the same directory and renamed into place,
so a reader (or a crash, or Ctrl-C) never sees a half-written result: the file is either
the previous one, or absent, or complete.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import tifffile
from numpy.typing import NDArray

from elphel_host.fileio import replacing
from elphel_host.preview import save_preview


def write_image(
    path: str | Path, image: NDArray[np.float32], *, as_float: bool, meta: dict[str, Any]
) -> dict[str, Any]:
    """Write ``image`` as a TIFF and ``path.with_suffix('.png')`` as a preview.

    Parameters
    ----------
    path
        The TIFF to write (parent directories are created).
    image
        (H, W) or (H, W, 3) float image in input units (DN).
    as_float
        Write float32 as it is; otherwise round to 16-bit DN, clipping (and counting)
        values outside 0..65535.
    meta
        JSON-able metadata for the TIFF's ImageDescription.

    Returns
    -------
    dict
        ``out`` (the TIFF), ``preview`` (the PNG) and ``clipped_pixels``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rgb = image.ndim == 3
    if as_float:
        data: NDArray[Any] = image.astype(np.float32)
        clipped = 0
    else:
        r = np.rint(image)
        clipped = int(np.count_nonzero((r < 0) | (r > 65535)))
        data = np.clip(r, 0, 65535).astype(np.uint16)
    png = path.with_suffix(".png")
    # the preview is renamed first (the inner block): whoever sees the TIFF finds its
    # preview next to it; the suffixes stay last, as tifffile and PIL choose formats by them
    with (
        replacing(path, sync=True, keep_suffix=True) as tmp_tif,
        replacing(png, sync=True, keep_suffix=True) as tmp_png,
    ):
        tifffile.imwrite(tmp_tif, data, photometric="rgb" if rgb else "minisblack", metadata=meta)
        save_preview(image, tmp_png)
    return {"out": str(path), "preview": str(png), "clipped_pixels": clipped}


def fused_meta(*, method: str, scale: int, burst: str | Path, bayer: str | None) -> dict[str, Any]:
    """The TIFF metadata written with a fused image (ImageDescription JSON)."""
    return {
        "method": method,
        "scale": scale,
        "burst": str(burst),
        "bayer": bayer,
        "grid": "cv2.resize: LR pixel i centre at scale*i + (scale-1)/2",
    }
