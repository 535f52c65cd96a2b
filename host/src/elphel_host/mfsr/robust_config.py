"""Options of the robust reconstruction: one frozen, checked :class:`RobustConfig`.

:func:`elphel_host.mfsr.robust.reconstruct` takes them; :data:`DEFAULT_CONFIG` is what it
uses when given none.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from elphel_host.mfsr.psf import MAX_SIGMA
from elphel_host.mfsr.psf_given import MAX_REGIONS, check_kernel, check_kernel_grid


@dataclass(frozen=True)
class RobustConfig:
    """Options of the robust reconstruction.

    Parameters
    ----------
    passes
        Robust passes after the first least-squares solve (each refines shifts and clips
        outliers).
    huber
        Residuals beyond this many noise sigmas are clipped.
    tau
        Expected HR gradient standard deviation as a fraction of the image's range; a
        smaller value smooths more.
    blur_sigma
        Extra Gaussian blur of the optics in HR px, deconvolved with the pixel aperture.
    prior_sigma
        Softness (Gaussian sigma, HR px) the prior expects of the HR image itself: it
        shapes the denoising (the prior's weight grows with frequency by the inverse of
        that Gaussian's power), it is not deconvolved.
    pad
        Mirror padding in LR px around each frame.
    refine
        Refine shifts against the model in the robust passes.
    refine_window
        Frames larger than this (px) have their shifts refined on a central window of
        this size, which costs a fraction of refining on the whole frame.
    noise_sigma
        Noise standard deviation in input units; None estimates it from the data.
    estimate_psf
        With ``blur_sigma`` 0 and no ``psf_kernel`` (the default): estimate the burst's
        apparent softness (and the prior's tau with it) by cross-validation
        (:mod:`elphel_host.mfsr.psf`), deconvolve the part beyond a scene's own softness
        and shape the prior with the rest. False: the pixel aperture alone. A given
        ``blur_sigma``, ``prior_sigma``, ``psf_kernel`` or ``psf_grid`` is used instead of
        an estimate; with ``estimate_psf`` its prior's tau is still cross-validated (False:
        ``tau`` as it is).
    psf_kernel
        A given PSF on the output's HR grid (:func:`elphel_host.mfsr.psf_given.check_kernel`),
        used in place of the Gaussian.
    psf_regions
        (rows, columns) of image regions fused each with its own PSF (estimated in each
        region, or ``psf_grid``'s) and blended (:mod:`elphel_host.mfsr.regions`); (1, 1):
        one PSF for the whole frame.
    psf_grid
        Given PSFs per region, ``(rows, columns, h, w)`` on the output's HR grid
        (:func:`elphel_host.mfsr.psf_given.check_kernel_grid`); sets ``psf_regions``.
    psf_rgb
        Given PSFs of a Bayer burst's red, green and blue planes, each reconstructed with
        its own: ``(3, h, w)`` beside ``psf_kernel``, or ``(3, rows, columns, h, w)``
        beside ``psf_grid`` (each colour's grid; e.g. a quad's per-colour calibration,
        :mod:`elphel_host.mfsr.psf_tp`). ``psf_kernel`` / ``psf_grid`` is the one used
        where one PSF serves (mono bursts, the green plane's estimates).
    psf_frame
        (height, width) of the frames a given PSF or grid was made for (e.g. a quad's
        calibration, :mod:`elphel_host.mfsr.psf_tp`); frames of another size are refused.
    fit_noise
        Estimate the noise from the residuals of a weakly regularised fit of the burst
        (:func:`~elphel_host.mfsr.robust.fit_noise`) when there are enough frames; False:
        from the reference frame alone (:func:`~elphel_host.mfsr.frames.estimate_noise`),
        which reads fine texture as noise.
    """

    passes: int = 1
    huber: float = 3.0
    tau: float = 0.04
    blur_sigma: float = 0.0
    prior_sigma: float = 0.0
    pad: int = 16
    refine: bool = True
    refine_window: int = 384
    noise_sigma: float | None = None
    fit_noise: bool = True
    estimate_psf: bool = True
    psf_kernel: NDArray[np.float64] | None = field(default=None, compare=False, repr=False)
    psf_regions: tuple[int, int] = (1, 1)
    psf_grid: NDArray[np.float64] | None = field(default=None, compare=False, repr=False)
    psf_rgb: NDArray[np.float64] | None = field(default=None, compare=False, repr=False)
    psf_frame: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        if self.passes < 0:
            raise ValueError(f"passes={self.passes}; allowed: >= 0")
        if not self.huber > 0:
            raise ValueError(f"huber={self.huber}; allowed: > 0")
        if not self.tau > 0:
            raise ValueError(f"tau={self.tau}; allowed: > 0")
        if not 0 <= self.blur_sigma <= MAX_SIGMA:
            raise ValueError(f"blur_sigma={self.blur_sigma}; allowed: 0..{MAX_SIGMA} (HR px)")
        if not 0 <= self.prior_sigma <= MAX_SIGMA:
            raise ValueError(f"prior_sigma={self.prior_sigma}; allowed: 0..{MAX_SIGMA} (HR px)")
        if self.psf_kernel is not None:
            object.__setattr__(self, "psf_kernel", check_kernel(self.psf_kernel, "psf_kernel"))
            if self.blur_sigma > 0:
                raise ValueError("psf_kernel: allowed only without blur_sigma")
        if self.psf_grid is not None:
            grid = check_kernel_grid(self.psf_grid)
            if self.psf_kernel is not None or self.blur_sigma > 0:
                raise ValueError("psf_grid: allowed only without psf_kernel and blur_sigma")
            if self.psf_regions not in ((1, 1), grid.shape[:2]):
                raise ValueError(f"psf_regions={self.psf_regions}; psf_grid has {grid.shape[:2]}")
            object.__setattr__(self, "psf_grid", grid)
            object.__setattr__(self, "psf_regions", (int(grid.shape[0]), int(grid.shape[1])))
        if self.psf_rgb is not None:
            object.__setattr__(self, "psf_rgb", self._checked_rgb(self.psf_rgb))
        ky, kx = self.psf_regions
        if not (1 <= ky <= MAX_REGIONS and 1 <= kx <= MAX_REGIONS):
            raise ValueError(f"psf_regions={self.psf_regions}; allowed: 1..{MAX_REGIONS} a side")
        if self.pad < 0:
            raise ValueError(f"pad={self.pad}; allowed: >= 0")
        if self.refine_window < 32:
            raise ValueError(f"refine_window={self.refine_window}; allowed: >= 32")

    def _checked_rgb(self, rgb: NDArray[np.float64]) -> NDArray[np.float64]:
        arr = np.asarray(rgb, dtype=np.float64)
        if arr.ndim == 3 and len(arr) == 3 and self.psf_kernel is not None:
            return np.stack([check_kernel(k, f"psf_rgb[{c}]") for c, k in enumerate(arr)])
        if arr.ndim == 5 and len(arr) == 3 and self.psf_grid is not None:
            grids = [check_kernel_grid(g, f"psf_rgb[{c}]") for c, g in enumerate(arr)]
            if grids[0].shape[:2] != self.psf_grid.shape[:2]:
                raise ValueError(
                    f"psf_rgb: {grids[0].shape[:2]} regions; psf_grid has {self.psf_grid.shape[:2]}"
                )
            return np.stack(grids)
        raise ValueError(
            f"psf_rgb: shape {arr.shape}; allowed: (3, h, w) with psf_kernel, or "
            "(3, rows, columns, h, w) with psf_grid"
        )


DEFAULT_CONFIG = RobustConfig()
