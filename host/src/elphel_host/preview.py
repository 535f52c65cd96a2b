"""8-bit previews of raw 16-bit frames, for people to look at."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from PIL import Image


def _stretch(a: NDArray[np.float64]) -> NDArray[np.uint8]:
    lo, hi = np.percentile(a, [0.5, 99.5])
    scaled = (a - lo) / max(hi - lo, 1e-12)
    out: NDArray[np.uint8] = (np.clip(scaled, 0, 1) ** (1 / 2.2) * 255 + 0.5).astype(np.uint8)
    return out


def preview_rgb(image: NDArray[Any], bayer: str | None) -> NDArray[np.uint8]:
    """Half-resolution RGB from a Bayer mosaic (each 2x2 cell one pixel), or grey for mono."""
    a = np.asarray(image, dtype=np.float64)
    if bayer is None:
        return _stretch(a)
    h, w = (a.shape[0] // 2) * 2, (a.shape[1] // 2) * 2
    cells = {
        (bayer[0], 0, 0): a[0:h:2, 0:w:2],
        (bayer[1], 0, 1): a[0:h:2, 1:w:2],
        (bayer[2], 1, 0): a[1:h:2, 0:w:2],
        (bayer[3], 1, 1): a[1:h:2, 1:w:2],
    }
    planes = {c: [v for (k, _, _), v in cells.items() if k == c] for c in "RGB"}
    rgb = np.stack([np.mean(planes[c], axis=0) for c in "RGB"], axis=-1)
    return _stretch(rgb)


def save_preview(image: NDArray[Any], path: str | Path, *, bayer: str | None = None) -> Path:
    """Write a PNG preview of a raw frame and return its path."""
    path = Path(path)
    Image.fromarray(preview_rgb(image, bayer)).save(path)
    return path
