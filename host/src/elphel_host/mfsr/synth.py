"""Synthetic bursts with known shifts, for tests and benchmarks.

A burst is made from a high-resolution (HR) image: each frame is the HR image translated
by ``scale * shift`` HR px (bicubic), area down-sampled by ``scale`` and given Gaussian
noise. Frame k's pixel i then sees the reference's LR coordinate ``i + shift_k`` and the
HR image is, by construction, the ground truth on the output grid of the MFSR methods
(``cv2.resize`` alignment).
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]


def area_downsample(image: NDArray[np.floating], scale: int) -> F32:
    """Mean over non-overlapping ``scale x scale`` cells (the image is cropped to fit)."""
    if image.ndim != 2:
        raise ValueError(f"image.ndim={image.ndim}; allowed: 2")
    h, w = (image.shape[0] // scale) * scale, (image.shape[1] // scale) * scale
    a = np.asarray(image[:h, :w], dtype=np.float32)
    return a.reshape(h // scale, scale, w // scale, scale).mean(axis=(1, 3), dtype=np.float32)


def shift_image(image: NDArray[np.floating], shift_yx: tuple[float, float]) -> F32:
    """Image whose pixel u shows the input at ``u + shift`` (bicubic, mirrored borders)."""
    dy, dx = shift_yx
    m = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy]], dtype=np.float64)
    src = np.asarray(image, dtype=np.float32)
    out = cv2.warpAffine(
        src,
        m,
        (src.shape[1], src.shape[0]),
        flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_REFLECT_101,
    )
    return np.asarray(out, dtype=np.float32)


def random_shifts(n: int, *, seed: int, spread: float = 1.0) -> NDArray[np.float64]:
    """First shift (0, 0), the others uniform in [-spread/2, spread/2)^2 LR px."""
    rng = np.random.default_rng(seed)
    s = rng.uniform(-spread / 2, spread / 2, size=(n, 2))
    s[0] = 0.0
    return s


def tilted_line_shifts(n: int, *, scale: int, step_px: float | None = None) -> NDArray[np.float64]:
    """Shifts of a 1-D stage whose axis is tilted by tan(theta) = 1/scale from the x axis."""
    step = scale / n if step_px is None else step_px
    x = np.arange(n, dtype=np.float64) * step
    return np.stack([x / scale, x], axis=1)


def make_burst(
    hr: NDArray[np.floating],
    shifts: Sequence[Sequence[float]] | NDArray[np.float64],
    *,
    scale: int,
    noise_sigma: float,
    seed: int,
) -> list[F32]:
    """LR frames of ``hr`` at the given (dy, dx) LR-pixel shifts.

    Parameters
    ----------
    hr
        2-D HR image (its size should be a multiple of ``scale``).
    shifts
        (N, 2) shifts in LR px; frame k pixel i sees reference LR coordinate i + shift_k.
    scale
        Down-sampling factor.
    noise_sigma
        Standard deviation of the added Gaussian noise, in the units of ``hr``.
    seed
        Seed of the noise generator.
    """
    if hr.ndim != 2:
        raise ValueError(f"hr.ndim={hr.ndim}; allowed: 2")
    if scale < 1:
        raise ValueError(f"scale={scale}; allowed: >= 1")
    rng = np.random.default_rng(seed)
    frames: list[F32] = []
    for dy, dx in np.asarray(shifts, dtype=np.float64):
        shifted = shift_image(hr, (scale * dy, scale * dx))
        lr = area_downsample(shifted, scale)
        if noise_sigma > 0:
            lr = lr + rng.normal(0.0, noise_sigma, lr.shape).astype(np.float32)
        frames.append(lr.astype(np.float32))
    return frames


def make_bayer_burst(
    rgb: NDArray[np.floating],
    shifts: Sequence[Sequence[float]] | NDArray[np.float64],
    *,
    scale: int,
    noise_sigma: float,
    seed: int,
    bayer: str = "GRBG",
) -> list[F32]:
    """Bayer mosaics of an HR RGB image at the given shifts: :func:`make_burst` per colour.

    Each colour is shifted, area down-sampled and given noise as :func:`make_burst` does
    (colour c with seed ``seed + c``); each frame keeps, at every site of the 2x2 cell, the
    colour ``bayer`` names there (row-major, e.g. ``GRBG``). ``rgb`` is (H, W, 3) with H
    and W multiples of ``2 * scale``.
    """
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"rgb.shape={rgb.shape}; allowed: (H, W, 3)")
    if sorted(bayer) != ["B", "G", "G", "R"]:
        raise ValueError(f"bayer={bayer!r}; allowed: a 2x2 pattern such as RGGB or GRBG")
    per = [
        make_burst(rgb[..., c], shifts, scale=scale, noise_sigma=noise_sigma, seed=seed + c)
        for c in range(3)
    ]
    frames: list[F32] = []
    for k in range(len(per[0])):
        mosaic = np.empty_like(per[0][k])
        for idx, colour in enumerate(bayer):
            oy, ox = idx // 2, idx % 2
            mosaic[oy::2, ox::2] = per["RGB".index(colour)][k][oy::2, ox::2]
        frames.append(mosaic)
    return frames
