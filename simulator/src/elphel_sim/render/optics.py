"""A lens's blur on the rendered radiance: a Gaussian point-spread function.

The renderer integrates the scene over each pixel's area; a real lens blurs the image
before the pixels integrate it. The two convolutions commute, so `blurred_strips`
renders the window with a margin, blurs each colour with a Gaussian of ``sigma_px``
sensor pixels on the pixel grid (a close approximation of blurring before the
integration for sigma >= 0.3 px) and crops the margin off. At the array's edges the
nearest pixel is repeated, as if the scene went on unchanged.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from elphel_sim.render.radiance import Intrinsics, Window, render_strips
from elphel_sim.world import FloatArray, Pose, World

#: Largest lens blur accepted (sensor px).
MAX_LENS_BLUR_PX = 5.0


def check_lens_blur(sigma_px: float) -> float:
    """``sigma_px`` if it is a Gaussian sigma the renderer accepts (0 = no blur)."""
    if not 0.0 <= sigma_px <= MAX_LENS_BLUR_PX:
        raise ValueError(f"lens blur {sigma_px} px; allowed: 0..{MAX_LENS_BLUR_PX} (sensor px)")
    return float(sigma_px)


def blurred_strips(
    world: World,
    intrinsics: Intrinsics,
    pose: Pose,
    *,
    window: Window,
    times_s: FloatArray,
    sigma_px: float,
) -> FloatArray:
    """`render_strips` of ``window`` seen through a Gaussian lens blur of ``sigma_px``."""
    if sigma_px <= 0:
        return render_strips(world, intrinsics, pose, window=window, times_s=times_s)
    left, top, width, height = window
    m = math.ceil(4.0 * sigma_px)
    x0, y0 = max(left - m, 0), max(top - m, 0)
    x1, y1 = min(left + width + m, intrinsics.width), min(top + height + m, intrinsics.height)
    wide = render_strips(
        world, intrinsics, pose, window=(x0, y0, x1 - x0, y1 - y0), times_s=times_s
    )
    out = ndimage.gaussian_filter(
        np.asarray(wide, dtype=np.float64), sigma=(0, sigma_px, sigma_px, 0), mode="nearest"
    )
    return np.ascontiguousarray(out[:, top - y0 : top - y0 + height, left - x0 : left - x0 + width])
