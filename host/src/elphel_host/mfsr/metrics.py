"""Image quality metrics: PSNR and SSIM (Wang et al. 2004, Gaussian window sigma 1.5)."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

Image = NDArray[np.floating]


def _check(
    reference: Image, image: Image, data_range: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    if reference.shape != image.shape:
        raise ValueError(f"image.shape={image.shape}; allowed: {reference.shape} (the reference's)")
    if reference.ndim != 2:
        raise ValueError(f"reference.ndim={reference.ndim}; allowed: 2")
    if not data_range > 0:
        raise ValueError(f"data_range={data_range}; allowed: > 0")
    return np.asarray(reference, np.float64), np.asarray(image, np.float64)


def psnr(reference: Image, image: Image, *, data_range: float, border: int = 0) -> float:
    """Peak signal-to-noise ratio in dB, ignoring ``border`` pixels on every side."""
    a, b = _check(reference, image, data_range)
    if border:
        a, b = a[border:-border, border:-border], b[border:-border, border:-border]
    mse = float(np.mean((a - b) ** 2))
    return float("inf") if mse == 0 else float(10.0 * np.log10(data_range**2 / mse))


def ssim(reference: Image, image: Image, *, data_range: float, border: int = 0) -> float:
    """Mean structural similarity (Gaussian 11x11 window, sigma 1.5, K1 0.01, K2 0.03)."""
    a, b = _check(reference, image, data_range)
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2

    def blur(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.asarray(cv2.GaussianBlur(x, (11, 11), 1.5, borderType=cv2.BORDER_REFLECT))

    mu_a, mu_b = blur(a), blur(b)
    va = blur(a * a) - mu_a**2
    vb = blur(b * b) - mu_b**2
    cov = blur(a * b) - mu_a * mu_b
    m = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a**2 + mu_b**2 + c1) * (va + vb + c2))
    crop = max(border, 5)
    return float(np.mean(m[crop:-crop, crop:-crop]))
