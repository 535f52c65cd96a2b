"""Frames on their way into a reconstruction: checked, cropped, aligned, padded, noise read.

These are the small steps the robust method (:mod:`elphel_host.mfsr.robust`) and the
registration share: one frame-list check, the central window both work on, the integer
alignment onto the reference grid with its validity mask, the padding that keeps the
periodic Fourier model seamless, and the single-frame noise estimate.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]

_LAPLACE_NOISE = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], dtype=np.float32)


def check_frames(frames: Sequence[NDArray[Any]]) -> tuple[int, int]:
    """The common (H, W) of a non-empty list of 2-D frames; ValueError names the odd one."""
    if not len(frames):
        raise ValueError("frames is empty; allowed: at least one frame")
    shape = frames[0].shape
    for i, f in enumerate(frames):
        if f.ndim != 2 or f.shape != shape:
            raise ValueError(f"frames[{i}].shape={f.shape}; allowed: {shape} (all alike, 2-D)")
    return int(shape[0]), int(shape[1])


def central_window(frames: Sequence[F32], size: int) -> list[F32]:
    """The central ``size`` x ``size`` window (or less, for smaller frames) of each frame."""
    h, w = frames[0].shape
    wy, wx = min(h, size), min(w, size)
    y0, x0 = (h - wy) // 2, (w - wx) // 2
    return [np.ascontiguousarray(f[y0 : y0 + wy, x0 : x0 + wx]) for f in frames]


def estimate_noise(image: F32) -> float:
    """Noise standard deviation of one frame (median of a Laplacian, robust to edges)."""
    if image.ndim != 2 or min(image.shape) < 3:
        raise ValueError(f"image.shape={image.shape}; allowed: 2-D, at least 3x3")
    f = cv2.filter2D(np.asarray(image, np.float32), -1, _LAPLACE_NOISE)[1:-1, 1:-1]
    step = max(1, int(np.sqrt(f.size / 250_000)))
    return float(np.median(np.abs(f[::step, ::step])) / 0.6745 / 6.0)


def aligned(frame: F32, reference: F32, n: tuple[int, int]) -> tuple[F32, NDArray[np.bool_]]:
    """Frame moved by the integer shift n onto the reference grid, with its validity mask."""
    h, w = frame.shape
    ny, nx = n
    if ny == 0 and nx == 0:
        return frame, np.ones(frame.shape, dtype=bool)
    # uncovered pixels start as the reference's (a fraction of a pixel off): they only
    # matter for the first solve; the robust passes replace them by the prediction
    out = np.array(reference, dtype=np.float32, copy=True)
    valid = np.zeros((h, w), dtype=bool)
    # out(q) = frame(q - n) where 0 <= q - n < size
    qy0, qy1 = max(0, ny), min(h, h + ny)
    qx0, qx1 = max(0, nx), min(w, w + nx)
    if qy1 > qy0 and qx1 > qx0:
        out[qy0:qy1, qx0:qx1] = frame[qy0 - ny : qy1 - ny, qx0 - nx : qx1 - nx]
        valid[qy0:qy1, qx0:qx1] = True
    return out, valid


def padded(a: NDArray[Any], pad: tuple[int, int, int, int], *, mode: str) -> NDArray[Any]:
    """``a`` padded by (top, bottom, left, right): mirrored (``reflect``) or with zeros."""
    top, bottom, left, right = pad
    if mode == "reflect":
        return np.asarray(cv2.copyMakeBorder(a, top, bottom, left, right, cv2.BORDER_REFLECT_101))
    h, w = a.shape
    out = np.zeros((h + top + bottom, w + left + right), a.dtype)
    out[top : top + h, left : left + w] = a
    return out
