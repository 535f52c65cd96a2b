"""Space-variant lens blur of a quad camera, and the kernels that correct it.

`aberrations` draws one random elliptical, slightly off-centre Gaussian PSF per camera,
colour and grid cell; `apply_aberrations` blurs a radiance image with them (the quad
renderer applies it before the mosaic); `correction_kernels` turns each PSF into one
common Gaussian, in the tile processor's kernel layout.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from elphel_sim.world import FloatArray

if TYPE_CHECKING:
    from elphel_sim.quad import QuadRig


@dataclass(frozen=True)
class Aberrations:
    """A space-variant blur per camera and colour: one 15x15 PSF per grid cell.

    ``psfs`` is ``(4, 3, ky, kx, 15, 15)`` in RGB order (row = 7 + dy); cell (kx, ky)
    covers pixels ``[kx*step, (kx+1)*step) x [ky*step, (ky+1)*step)``.
    """

    psfs: NDArray[np.float64]
    step: int


def aberrations(
    rig: QuadRig,
    *,
    seed: int,
    cells: tuple[int, int] = (2, 3),
    sigma_px: tuple[float, float] = (0.6, 1.2),
    max_offset_px: float = 0.3,
) -> Aberrations:
    """Random elliptical Gaussian PSFs, off-centre by up to ``max_offset_px``, per cell."""
    rng = np.random.default_rng(seed)
    ky, kx = cells
    step = int(np.ceil(max(rig.height / ky, rig.width / kx) / 8) * 8)
    ky, kx = -(-rig.height // step), -(-rig.width // step)
    yy, xx = np.mgrid[-7:8, -7:8].astype(np.float64)
    psfs = np.empty((4, 3, ky, kx, 15, 15))
    for idx in np.ndindex(4, 3, ky, kx):
        sx, sy = rng.uniform(*sigma_px, size=2)
        ang = rng.uniform(0, np.pi)
        ox, oy = rng.uniform(-max_offset_px, max_offset_px, size=2)
        c, s_ = np.cos(ang), np.sin(ang)
        u = c * (xx - ox) + s_ * (yy - oy)
        v = -s_ * (xx - ox) + c * (yy - oy)
        k = np.exp(-0.5 * ((u / sx) ** 2 + (v / sy) ** 2))
        psfs[idx] = k / k.sum()
    return Aberrations(psfs, step)


def apply_aberrations(rgb: FloatArray, psfs: NDArray[np.float64], step: int) -> FloatArray:
    """Blur an (H, W, 3) image with the PSF of the cell each pixel lies in."""
    h, w = rgb.shape[:2]
    out = np.empty_like(rgb)
    ky, kx = psfs.shape[1:3]
    for colour in range(3):
        for cy in range(ky):
            for cx in range(kx):
                y0, y1 = cy * step, min((cy + 1) * step, h)
                x0, x1 = cx * step, min((cx + 1) * step, w)
                if y0 >= y1 or x0 >= x1:
                    continue
                # convolve a margin-padded crop so the cell's pixels see their neighbours
                ya, yb, xa, xb = max(y0 - 8, 0), min(y1 + 8, h), max(x0 - 8, 0), min(x1 + 8, w)
                crop = ndimage.convolve(
                    rgb[ya:yb, xa:xb, colour], psfs[colour, cy, cx], mode="nearest"
                )
                out[y0:y1, x0:x1, colour] = crop[y0 - ya : y1 - ya, x0 - xa : x1 - xa]
    return out


def correction_kernels(
    ab: Aberrations, *, bayer: str | None, target_sigma_px: float = 1.3, eps: float = 1e-3
) -> NDArray[np.float32]:
    """Kernels that turn each camera's PSF into one common Gaussian (regularised inverse).

    Returns the tile processor's layout ``(4, colours, ky, kx, 15, 15)``: colours R, B, G
    for Bayer, one (the mean PSF's kernel) for mono.
    """
    n = 64
    f = np.fft.fftfreq(n)
    fr2 = f[:, None] ** 2 + f[None, :] ** 2
    target = np.exp(-2 * np.pi**2 * target_sigma_px**2 * fr2)
    psfs = ab.psfs
    if bayer is None:
        psfs = psfs.mean(axis=1, keepdims=True)
        order = [0]
    else:
        order = [0, 2, 1]  # RGB -> R, B, G
    out = np.empty((4, len(order), *psfs.shape[2:4], 15, 15), dtype=np.float32)
    for cam in range(4):
        for i, colour in enumerate(order):
            for cy, cx in np.ndindex(*psfs.shape[2:4]):
                big = np.zeros((n, n))
                big[:15, :15] = psfs[cam, colour, cy, cx]
                big = np.roll(big, (-7, -7), axis=(0, 1))  # centre at (0, 0)
                p = np.fft.fft2(big)
                kf = target * np.conj(p) / (np.abs(p) ** 2 + eps)
                k = np.roll(np.fft.ifft2(kf).real, (7, 7), axis=(0, 1))[:15, :15]
                out[cam, i, cy, cx] = k / k.sum()
    return out
