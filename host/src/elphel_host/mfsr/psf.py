"""Blind estimate of the optics' blur from a registered burst, by cross-validation.

Model: the optics add a Gaussian blur of ``sigma`` HR px to the pixel's box aperture (the
forward model of :mod:`elphel_host.mfsr.forward`). Sub-pixel shifted frames of one scene
determine the product of the blur's transfer and the image's spectrum at every alias, so
the blur is told apart from the image by the prior: the gradient prior says what an image
spectrum is expected to look like, and the sigma (with the prior's weight) that lets a
reconstruction from some frames best predict the frames it has not seen is the one whose
assumed spectrum matches the data's.

Procedure, on a central window of the burst (``window`` LR px): every candidate (sigma,
tau) is scored by how well reconstructions from some frames predict the others
(:mod:`elphel_host.mfsr.psf_cv`), and the least error wins. The search: tau over its
grid at sigma 0.8, sigma over its grid (0..1.6 HR px, steps of 0.2) at that tau, steps of
0.05 around the best, and a parabola through the best and its neighbours. A burst with
too few frames for a determined fit at the output scale is searched at a smaller scale
(x2) and the result converted to the output's HR px.

What the search finds is the burst's apparent softness: the lens's blur and the scene's
own softness together (Gaussian widths add in quadrature), which no burst tells apart, since
only their product is seen. Deconvolving a soft scene's own softness sharpens it beyond the
truth (up to 10 dB lost on band-limited scenes), so the estimate is split: the blur beyond
``SCENE_SOFTNESS`` sensor px (in quadrature) is deconvolved, and the rest, up to that much,
only shapes the prior (:attr:`ForwardModel.prior_sigma`), which denoises as the apparent
softness asks without sharpening anything.

A given PSF (a calibrated lens: a sigma, a kernel, a region's kernel) gets its prior's tau
from the same cross-validation with the optics fixed (``estimate_psf(..., given=PSF)``).

Confidence: the prediction error of each sigma is compared with the best's fold by fold;
the sigmas whose excess is within two standard errors (over the folds) of zero form the
``interval``, and ``confidence`` is ``1 - width / 0.5`` (clipped to 0..1): 1 when one
sigma of the grid stands out, 0 when an interval of 0.5 HR px fits as well.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elphel_host.mfsr.psf_cv import CrossValidation

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

#: Coarse grids of the search: blur sigma (HR px) and the prior's tau (fraction of range).
SIGMA_GRID = tuple(round(0.2 * i, 2) for i in range(9))  # 0 .. 1.6
TAU_GRID = (0.02, 0.03, 0.04, 0.06, 0.08, 0.12)
MAX_SIGMA = 3.0
#: Softness (Gaussian sigma, in sensor pixels) a sharp scene's own detail can show in a
#: burst: only apparent blur beyond it is deconvolved. The benchmark's blur-free bursts
#: (photographs at their native resolution, the simulator's band-limited texture) show
#: 0.08-0.38 sensor px; deconvolving their apparent softness costs them up to 10 dB.
SCENE_SOFTNESS = 0.3


@dataclass(frozen=True)
class PsfEstimate:
    """The optics' blur used by a reconstruction.

    Attributes
    ----------
    model
        ``"gaussian"`` (a Gaussian of ``sigma`` HR px on top of the pixel aperture),
        ``"kernel"`` (a given PSF on the HR grid, ``kernel``) or ``"none"`` (the pixel
        aperture alone).
    sigma
        Gaussian sigma in HR px (0 for ``"none"``).
    source
        ``"estimated"`` (from the burst), ``"given"`` or ``"disabled"``.
    tau
        The prior strength chosen with it (fraction of the image range), or None when
        the default is kept.
    confidence
        0..1 (see the module notes); None unless estimated.
    interval
        (low, high) sigmas the burst cannot tell from the estimate; None unless estimated.
    cv_error_ratio
        Prediction error of held-out frames with the estimate, over that without blur
        (< 1: the blur explains the data better); None unless estimated.
    prior_sigma
        Softness (HR px) the prior is shaped by, not deconvolved
        (:attr:`~elphel_host.mfsr.forward.ForwardModel.prior_sigma`).
    apparent_sigma
        The burst's apparent softness (HR px) the search found, before the split into
        ``sigma`` and ``prior_sigma``; None unless estimated.
    """

    model: str
    sigma: float
    source: str
    tau: float | None = None
    confidence: float | None = None
    interval: tuple[float, float] | None = None
    cv_error_ratio: float | None = None
    prior_sigma: float = 0.0
    apparent_sigma: float | None = None
    kernel: NDArray[np.float64] | None = field(default=None, compare=False, repr=False)

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "model": self.model,
            "sigma_hr_px": round(self.sigma, 4),
            "source": self.source,
        }
        if self.kernel is not None:
            out["kernel_shape"] = list(self.kernel.shape)
        if self.apparent_sigma is not None:
            out["apparent_sigma_hr_px"] = round(self.apparent_sigma, 4)
        if self.prior_sigma:
            out["prior_sigma_hr_px"] = round(self.prior_sigma, 4)
        if self.tau is not None:
            out["tau"] = self.tau
        if self.confidence is not None:
            out["confidence"] = round(self.confidence, 3)
        if self.interval is not None:
            out["interval_hr_px"] = [round(v, 3) for v in self.interval]
        if self.cv_error_ratio is not None:
            out["cv_error_ratio"] = round(self.cv_error_ratio, 5)
        return out


NO_BLUR = PsfEstimate("none", 0.0, "disabled")


def estimate_psf(
    frames: Sequence[F32],
    shifts: Sequence[tuple[float, float]],
    *,
    scale: int,
    aperture: int | None = None,
    origin_shift: tuple[float, float] = (0.0, 0.0),
    noise_sigma: float | None = None,
    window: int = 128,
    folds: int = 4,
    choose_tau: bool = True,
    default_tau: float = 0.04,
    given: PsfEstimate | None = None,
) -> PsfEstimate:
    """Gaussian blur of the optics (HR px) from a registered burst, by cross-validation.

    Parameters
    ----------
    frames, shifts, scale, aperture, origin_shift
        As for :func:`elphel_host.mfsr.robust.reconstruct` (shifts as refined there are
        best: the estimate trusts them).
    noise_sigma
        Noise standard deviation (input units) that sets the prior's weight with tau;
        None: a single frame's estimate.
    window
        Central window (LR px) the search runs on.
    folds
        Cross-validation groups (frames k with ``k % folds == g``); every training set
        must keep at least ``scale**2`` frames.
    choose_tau
        Choose tau jointly with sigma (else ``default_tau`` is kept).
    given
        Optics not to search (``source="given"``: a Gaussian, a kernel on the output's HR
        grid, a prior shape): only the prior's tau is chosen for them, and ``given`` is
        returned with it (with ``tau`` None when a kernel cannot be used at the scale the
        fit must run at, a smaller one than the output's).

    Returns
    -------
    PsfEstimate
        ``source="estimated"``: ``apparent_sigma`` what the search found, ``sigma`` the
        blur to deconvolve (model ``"none"`` when it comes out below 0.05 HR px) and
        ``prior_sigma`` the softness left to the prior; ``sigma`` and ``prior_sigma`` are
        0 when the search's interval reaches 0.
    """
    cv = CrossValidation(frames, shifts, scale, aperture, origin_shift, noise_sigma, window, folds)
    fit_scale = cv.fit_scale
    to_fit = fit_scale / float(scale)  # output HR px -> fit HR px
    if given is not None:
        if given.kernel is not None and fit_scale != int(scale):
            return given
        sig, pri = given.sigma * to_fit, given.prior_sigma * to_fit
        tau = min(TAU_GRID, key=lambda t: float(cv.errors(sig, t, given.kernel, pri).sum()))
        return replace(given, tau=tau)

    cache: dict[tuple[float, float], F64] = {}

    def errs(sig: float, tau: float) -> F64:
        key = (round(sig, 4), tau)
        if key not in cache:
            cache[key] = cv.errors(sig, tau)
        return cache[key]

    # coordinate search: tau at a middle sigma, sigma at that tau, then finer sigma steps
    # around the best (each candidate's errors are kept)
    def total(st: tuple[float, float]) -> float:
        return float(errs(*st).sum())

    taus = TAU_GRID if choose_tau else (default_tau,)
    tau = min(taus, key=lambda t: total((SIGMA_GRID[len(SIGMA_GRID) // 2], t)))
    sig0 = min(SIGMA_GRID, key=lambda sg: total((sg, tau)))
    fine = sorted(
        {round(sig0 + d, 3) for d in np.arange(-0.1, 0.101, 0.05) if sig0 + d >= 0}
        | set(SIGMA_GRID)
    )
    curve = {sg: errs(sg, tau) for sg in fine}
    s_best = min(curve, key=lambda s: curve[s].sum())
    i = fine.index(s_best)
    sigma = float(s_best)
    if 0 < i < len(fine) - 1:  # parabola through the best and its neighbours
        x0, x1, x2 = fine[i - 1], fine[i], fine[i + 1]
        y0, y1, y2 = (curve[x].sum() for x in (x0, x1, x2))
        den = (x0 - x1) * (x0 - x2) * (x1 - x2)
        a = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / den
        b = (x2 * x2 * (y0 - y1) + x1 * x1 * (y2 - y0) + x0 * x0 * (y1 - y2)) / den
        if a > 0:
            sigma = float(np.clip(-b / (2 * a), x0, x2))
    # sigmas the folds cannot tell from the best: paired excess within 2 standard errors
    e_best = curve[s_best]
    within = []
    for s in fine:
        d = curve[s] - e_best
        se = float(np.std(d, ddof=1) / np.sqrt(len(d))) if len(d) > 1 else 0.0
        if d.mean() <= 2 * se:
            within.append(s)
    interval = (float(min(within)), float(max(within)))
    confidence = float(np.clip(1.0 - (interval[1] - interval[0]) / 0.5, 0.0, 1.0))
    ratio = float(e_best.sum() / errs(0.0, tau).sum())
    to_out = float(scale) / fit_scale  # fit HR px -> output HR px
    sigma, interval = sigma * to_out, (interval[0] * to_out, interval[1] * to_out)
    # a burst that cannot tell its softness from none gets the plain model; otherwise the
    # blur beyond a scene's own softness is deconvolved and the rest shapes the prior
    told = interval[0] > 0
    soft = SCENE_SOFTNESS * int(aperture or scale)
    blur = float(np.sqrt(max(sigma * sigma - soft * soft, 0.0))) if told else 0.0
    if blur < 0.05:
        blur = 0.0
    return PsfEstimate(
        "gaussian" if blur else "none",
        blur,
        "estimated",
        tau=tau if choose_tau else None,
        confidence=confidence,
        interval=interval,
        cv_error_ratio=ratio,
        prior_sigma=float(np.sqrt(max(sigma * sigma - blur * blur, 0.0))) if told else 0.0,
        apparent_sigma=sigma,
    )
