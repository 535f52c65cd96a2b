"""A lens's blur on the rendered radiance: a Gaussian point-spread function.

The renderer integrates the scene over each pixel's area; a real lens blurs the image
before the pixels integrate it. The two convolutions commute, so `blurred_strips`
renders the window with a margin, blurs each colour with a Gaussian of the lens's sigma
(sensor pixels) on the pixel grid (a close approximation of blurring before the
integration for sigma >= 0.3 px) and crops the margin off. At the array's edges the
nearest pixel is repeated, as if the scene went on unchanged.

A lens's PSF is the host's :class:`~elphel_host.mfsr.gaussian_psf.GaussianPsf` (round,
sensor px). A blur that varies over the field (`LensBlur` with ``edge``) grows with the squared
distance from the optical centre; it is rendered as the per-pixel linear interpolation
between the image blurred at `LEVELS` sigmas spanning the lens's range (only those a
window needs are computed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from elphel_host.mfsr.gaussian_psf import GaussianPsf
from elphel_sim.render.radiance import Intrinsics, Window, render_strips
from elphel_sim.world import FloatArray, Pose, World

#: Largest lens blur accepted (sensor px).
MAX_LENS_BLUR_PX = 5.0
#: Sigmas a field-varying blur is interpolated between.
LEVELS = 5


def check_lens_blur(sigma_px: float) -> float:
    """``sigma_px`` if it is a Gaussian sigma the renderer accepts (0 = no blur)."""
    if not 0.0 <= sigma_px <= MAX_LENS_BLUR_PX:
        raise ValueError(f"lens blur {sigma_px} px; allowed: 0..{MAX_LENS_BLUR_PX} (sensor px)")
    return float(sigma_px)


def _round_sigma_px(psf: GaussianPsf, where: str) -> float:
    sigma = psf.sigma_px
    if sigma is None:
        raise ValueError(
            f"lens blur {where} {psf.cov.tolist()} offset {psf.offset}; allowed: a round, "
            "centred Gaussian (GaussianPsf.round)"
        )
    return check_lens_blur(sigma)


@dataclass(frozen=True)
class LensBlur:
    """A lens's blur: round Gaussian PSFs in sensor px over the field.

    ``centre`` on the optical axis; with ``edge`` the sigma grows with the squared distance
    from the axis to ``edge``'s at the array's farthest corner (None: ``centre`` everywhere).
    """

    centre: GaussianPsf = field(default_factory=lambda: GaussianPsf.round(0.0))
    edge: GaussianPsf | None = None

    def __post_init__(self) -> None:
        _round_sigma_px(self.centre, "centre")
        if self.edge is not None:
            _round_sigma_px(self.edge, "edge")

    @classmethod
    def parse(cls, text: str) -> LensBlur:
        """``C`` (the same everywhere) or ``C:E`` (centre, corner; sensor px); else ValueError."""
        parts = text.split(":")
        if len(parts) > 2:
            raise ValueError(f"lens blur {text!r}; allowed: C or C:E (sensor px)")
        psfs = [GaussianPsf.round(check_lens_blur(float(p))) for p in parts]
        return cls(psfs[0], psfs[1] if len(psfs) == 2 else None)

    @property
    def centre_px(self) -> float:
        """The sigma on the optical axis."""
        return _round_sigma_px(self.centre, "centre")

    @property
    def corner_px(self) -> float:
        """The sigma at the array's farthest corner."""
        return self.centre_px if self.edge is None else _round_sigma_px(self.edge, "edge")

    @property
    def varies(self) -> bool:
        return self.corner_px != self.centre_px

    def to_json(self) -> dict[str, float | None]:
        edge = None if self.edge is None else self.corner_px
        return {"lens_blur_px": self.centre_px, "lens_blur_edge_px": edge}

    def sigma_at(self, intrinsics: Intrinsics, ys: FloatArray, xs: FloatArray) -> FloatArray:
        """The sigma at pixel centres (rows ``ys``, columns ``xs``; an open grid)."""
        if not self.varies:
            return np.full(np.broadcast_shapes(ys.shape, xs.shape), self.centre_px)
        cx, cy = intrinsics.principal_point
        w, h = intrinsics.width, intrinsics.height
        r2_max = max(cx, w - cx) ** 2 + max(cy, h - cy) ** 2
        r2 = (xs + 0.5 - cx) ** 2 + (ys + 0.5 - cy) ** 2
        out: FloatArray = self.centre_px + (self.corner_px - self.centre_px) * (r2 / r2_max)
        return out


def blurred_strips(
    world: World,
    intrinsics: Intrinsics,
    pose: Pose,
    *,
    window: Window,
    times_s: FloatArray,
    blur: LensBlur,
) -> FloatArray:
    """`render_strips` of ``window`` seen through the lens blur ``blur``."""
    if blur.centre_px <= 0 and blur.corner_px <= 0:
        return render_strips(world, intrinsics, pose, window=window, times_s=times_s)
    left, top, width, height = window
    m = math.ceil(4.0 * max(blur.centre_px, blur.corner_px))
    x0, y0 = max(left - m, 0), max(top - m, 0)
    x1, y1 = min(left + width + m, intrinsics.width), min(top + height + m, intrinsics.height)
    wide = np.asarray(
        render_strips(world, intrinsics, pose, window=(x0, y0, x1 - x0, y1 - y0), times_s=times_s),
        dtype=np.float64,
    )
    sig = blur.sigma_at(
        intrinsics,
        np.arange(y0, y1, dtype=np.float64)[:, None],
        np.arange(x0, x1, dtype=np.float64)[None, :],
    )
    # the lens's levels, not the window's: a window is blurred as the whole array is
    lo, hi = sorted((blur.centre_px, blur.corner_px))
    levels = np.linspace(lo, hi, LEVELS) if blur.varies else np.array([lo])
    out = np.zeros_like(wide)
    pos = (sig - lo) / max(hi - lo, 1e-12) * (len(levels) - 1)
    for k, s in enumerate(levels):
        weight = np.clip(1.0 - np.abs(pos - k), 0.0, 1.0)  # hat functions: they sum to 1
        if not weight.any():
            continue
        level = ndimage.gaussian_filter(wide, sigma=(0, s, s, 0), mode="nearest") if s > 0 else wide
        out += level * weight[None, :, :, None]
    return np.ascontiguousarray(out[:, top - y0 : top - y0 + height, left - x0 : left - x0 + width])


#: A perfectly sharp lens.
SHARP = LensBlur()
