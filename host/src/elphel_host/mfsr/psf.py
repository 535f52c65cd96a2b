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
from the same cross-validation with the optics fixed (:func:`cross_validated_tau`).

Confidence: the prediction error of each sigma is compared with the best's fold by fold;
the sigmas whose excess is within two standard errors (over the folds) of zero form the
``interval``, and ``confidence`` is ``1 - width / 0.5`` (clipped to 0..1): 1 when one
sigma of the grid stands out, 0 when an interval of 0.5 HR px fits as well.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elphel_host.mfsr.forward import threads_for
from elphel_host.mfsr.psf_cv import CrossValidation
from elphel_host.parallel import parallel_map

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

#: Coarse grids of the search: blur sigma (HR px) and the prior's tau (fraction of range).
SIGMA_GRID = tuple(round(0.2 * i, 2) for i in range(9))  # 0 .. 1.6
TAU_GRID = (0.02, 0.03, 0.04, 0.06, 0.08, 0.12)
#: Softness (Gaussian sigma, in sensor pixels) a sharp scene's own detail can show in a
#: burst: only apparent blur beyond it is deconvolved. The benchmark's blur-free bursts
#: (photographs at their native resolution, the simulator's band-limited texture) show
#: 0.08-0.38 sensor px; deconvolving their apparent softness costs them up to 10 dB.
SCENE_SOFTNESS = 0.3


@dataclass(frozen=True)
class Optics:
    """The optics a reconstruction's forward model uses, on its HR grid.

    Attributes
    ----------
    blur_sigma
        Gaussian blur (HR px) deconvolved on top of the pixel aperture; 0: none.
    kernel
        A PSF on the HR grid used in place of the Gaussian (sum 1, odd sides); None: none.
    prior_sigma
        Softness (HR px) the prior is shaped by, not deconvolved
        (:attr:`~elphel_host.mfsr.forward.ForwardModel.prior_sigma`).
    """

    blur_sigma: float = 0.0
    kernel: F64 | None = field(default=None, compare=False, repr=False)
    prior_sigma: float = 0.0

    def __post_init__(self) -> None:
        if self.kernel is not None and self.blur_sigma > 0:
            raise ValueError(f"blur_sigma={self.blur_sigma} with a kernel; allowed: one of them")
        if not (self.blur_sigma >= 0 and self.prior_sigma >= 0):
            raise ValueError(
                f"blur_sigma={self.blur_sigma}, prior_sigma={self.prior_sigma}; allowed: >= 0"
            )

    @property
    def model(self) -> str:
        """``"kernel"``, ``"gaussian"`` or ``"none"`` (the pixel aperture alone)."""
        if self.kernel is not None:
            return "kernel"
        return "gaussian" if self.blur_sigma > 0 else "none"

    def at_scale(self, factor: float) -> Optics:
        """The optics on an HR grid ``factor`` times as fine (a kernel only at factor 1)."""
        kernel = self.kernel if factor == 1 else None
        return Optics(self.blur_sigma * factor, kernel, self.prior_sigma * factor)

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"model": self.model, "sigma_hr_px": round(self.blur_sigma, 4)}
        if self.kernel is not None:
            out["kernel_shape"] = list(self.kernel.shape)
        if self.prior_sigma:
            out["prior_sigma_hr_px"] = round(self.prior_sigma, 4)
        return out


NO_OPTICS = Optics()


@dataclass(frozen=True)
class BlurEstimate:
    """The blur :func:`estimate_psf` found in a burst.

    Attributes
    ----------
    optics
        What to deconvolve (``blur_sigma``) and what to leave to the prior (``prior_sigma``).
    apparent_sigma
        The burst's apparent softness (HR px) the search found, before that split.
    tau
        The prior strength chosen with it (fraction of the image range); None when the
        default is kept.
    confidence
        0..1 (see the module notes).
    interval
        (low, high) sigmas the burst cannot tell from the estimate.
    cv_error_ratio
        Prediction error of held-out frames with the estimate, over that without blur
        (< 1: the blur explains the data better).
    """

    optics: Optics
    apparent_sigma: float
    tau: float | None
    confidence: float
    interval: tuple[float, float]
    cv_error_ratio: float

    def to_json(self) -> dict[str, Any]:
        out = {**self.optics.to_json(), "source": "estimated"}
        out["apparent_sigma_hr_px"] = round(self.apparent_sigma, 4)
        if self.tau is not None:
            out["tau"] = self.tau
        out["confidence"] = round(self.confidence, 3)
        out["interval_hr_px"] = [round(v, 3) for v in self.interval]
        out["cv_error_ratio"] = round(self.cv_error_ratio, 5)
        return out


def cross_validated_tau(
    frames: Sequence[F32],
    shifts: Sequence[tuple[float, float]],
    optics: Optics,
    *,
    scale: int,
    aperture: int | None = None,
    origin_shift: tuple[float, float] = (0.0, 0.0),
    noise_sigma: float | None = None,
    window: int = 128,
) -> float | None:
    """The prior's tau (of :data:`TAU_GRID`) that best predicts held-out frames with ``optics``.

    Arguments as for :func:`estimate_psf`. None when ``optics`` has a kernel and the fit
    must run at a smaller scale than the output's, where the kernel does not apply.
    """
    cv = CrossValidation(frames, shifts, scale, aperture, origin_shift, noise_sigma, window, 4)
    if optics.kernel is not None and cv.fit_scale != int(scale):
        return None
    fit = optics.at_scale(cv.fit_scale / float(scale))
    totals = parallel_map(
        lambda t: float(cv.errors(fit.blur_sigma, t, fit.kernel, fit.prior_sigma).sum()),
        TAU_GRID,
        threads=threads_for(cv.shape),
    )
    return TAU_GRID[int(np.argmin(totals))]


class _Search:
    """Cross-validation errors per (sigma, tau) on one burst window, each computed once."""

    def __init__(self, cv: CrossValidation) -> None:
        self.cv = cv
        self.cache: dict[tuple[float, float], F64] = {}

    def errs(self, sig: float, tau: float) -> F64:
        key = (round(sig, 4), tau)
        if key not in self.cache:
            self.cache[key] = self.cv.errors(sig, tau)
        return self.cache[key]

    def fill(self, candidates: Sequence[tuple[float, float]]) -> None:
        """Compute the candidates (sigma, tau) not yet known, on every core."""
        todo = sorted({(round(sg, 4), t) for sg, t in candidates} - set(self.cache))
        errors = parallel_map(
            lambda c: self.cv.errors(*c), todo, threads=threads_for(self.cv.shape)
        )
        for key, e in zip(todo, errors, strict=True):
            self.cache[key] = e

    def total(self, sig: float, tau: float) -> float:
        return float(self.errs(sig, tau).sum())

    # a coordinate search: tau at a middle sigma, sigma at that tau, then finer sigma
    # steps around the best (each candidate's errors are kept)
    def tau(self, taus: Sequence[float]) -> float:
        """The tau of ``taus`` with the least error at the middle sigma of the grid."""
        self.fill([(SIGMA_GRID[len(SIGMA_GRID) // 2], t) for t in taus])
        return min(taus, key=lambda t: self.total(SIGMA_GRID[len(SIGMA_GRID) // 2], t))

    def curve(self, tau: float) -> tuple[list[float], dict[float, F64]]:
        """Sigmas of the grid and 0.05 steps around its best at ``tau``, with their errors."""
        self.fill([(sg, tau) for sg in SIGMA_GRID])
        sig0 = min(SIGMA_GRID, key=lambda sg: self.total(sg, tau))
        fine = sorted(
            {round(sig0 + d, 3) for d in np.arange(-0.1, 0.101, 0.05) if sig0 + d >= 0}
            | set(SIGMA_GRID)
        )
        self.fill([(sg, tau) for sg in fine])
        return fine, {sg: self.errs(sg, tau) for sg in fine}


def _parabola_min(fine: list[float], curve: dict[float, F64], i: int) -> float:
    """The minimum of the parabola through ``fine[i]`` and its neighbours (their errors)."""
    x0, x1, x2 = fine[i - 1], fine[i], fine[i + 1]
    y0, y1, y2 = (curve[x].sum() for x in (x0, x1, x2))
    den = (x0 - x1) * (x0 - x2) * (x1 - x2)
    a = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / den
    b = (x2 * x2 * (y0 - y1) + x1 * x1 * (y2 - y0) + x0 * x0 * (y1 - y2)) / den
    if a > 0:
        return float(np.clip(-b / (2 * a), x0, x2))
    return float(x1)


def _interval(curve: dict[float, F64], s_best: float) -> tuple[float, float]:
    """Sigmas the folds cannot tell from the best: paired excess within 2 standard errors."""
    e_best = curve[s_best]
    within = []
    for s, e in curve.items():
        d = e - e_best
        se = float(np.std(d, ddof=1) / np.sqrt(len(d))) if len(d) > 1 else 0.0
        if d.mean() <= 2 * se:
            within.append(s)
    return float(min(within)), float(max(within))


def _split(sigma: float, interval: tuple[float, float], aperture: int) -> Optics:
    """The apparent softness split into the blur deconvolved and the prior's share.

    A burst that cannot tell its softness from none gets the plain model; otherwise the
    blur beyond a scene's own softness is deconvolved and the rest shapes the prior.
    """
    if interval[0] <= 0:
        return NO_OPTICS
    soft = SCENE_SOFTNESS * aperture
    blur = float(np.sqrt(max(sigma * sigma - soft * soft, 0.0)))
    if blur < 0.05:
        blur = 0.0
    return Optics(blur, None, float(np.sqrt(max(sigma * sigma - blur * blur, 0.0))))


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
) -> BlurEstimate:
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
    default_tau
        The prior's tau when it is not chosen.

    Returns
    -------
    BlurEstimate
        ``apparent_sigma`` what the search found, ``optics.blur_sigma`` the blur to
        deconvolve (0 when it comes out below 0.05 HR px) and ``optics.prior_sigma`` the
        softness left to the prior; both 0 when the search's interval reaches 0.
    """
    cv = CrossValidation(frames, shifts, scale, aperture, origin_shift, noise_sigma, window, folds)
    search = _Search(cv)
    tau = search.tau(TAU_GRID if choose_tau else (default_tau,))
    fine, curve = search.curve(tau)
    s_best = min(curve, key=lambda s: curve[s].sum())
    i = fine.index(s_best)
    sigma = _parabola_min(fine, curve, i) if 0 < i < len(fine) - 1 else float(s_best)
    interval = _interval(curve, s_best)
    confidence = float(np.clip(1.0 - (interval[1] - interval[0]) / 0.5, 0.0, 1.0))
    ratio = float(curve[s_best].sum() / search.errs(0.0, tau).sum())
    to_out = float(scale) / cv.fit_scale  # fit HR px -> output HR px
    sigma, interval = sigma * to_out, (interval[0] * to_out, interval[1] * to_out)
    return BlurEstimate(
        optics=_split(sigma, interval, int(aperture or scale)),
        apparent_sigma=sigma,
        tau=tau if choose_tau else None,
        confidence=confidence,
        interval=interval,
        cv_error_ratio=ratio,
    )
