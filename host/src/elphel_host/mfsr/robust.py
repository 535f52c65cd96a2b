"""``robust`` fusion: the PSF resolved once, then the noise, the shifts and the solve.

:func:`reconstruct` is the orchestrator, in explicit steps:

1. :func:`resolve_psf` turns the configured :data:`~elphel_host.mfsr.psf_spec.PsfSpec`
   into concrete optics and a prior's tau: given optics as they are, or the blur estimated
   (:mod:`elphel_host.mfsr.psf`) on a 128 px central window that is first reconstructed
   to refine its shifts and measure its noise; a given PSF gets its prior's tau
   cross-validated the same way.
2. The noise: given, or the smaller of a single frame's estimate and a fit of the burst
   (:func:`~elphel_host.mfsr.solve.fit_noise`); a single frame cannot tell fine, aliased
   texture from noise.
3. Frames larger than ``refine_window`` have their shifts refined on a central window of
   that size (same model, exact, a fraction of the work); the full-size passes then only
   clip outliers.
4. :func:`~elphel_host.mfsr.solve.solve` with those optics, tau, noise and shifts.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elphel_host.mfsr.frames import central_window, check_frames, estimate_noise
from elphel_host.mfsr.gaussian_psf import GaussianPsf
from elphel_host.mfsr.psf import NO_OPTICS, Optics, cross_validated_tau, estimate_psf
from elphel_host.mfsr.psf_spec import EstimateBlur, GivenGrid, GivenKernel, NoBlur, PsfSpec
from elphel_host.mfsr.robust_config import DEFAULT_CONFIG, RobustConfig
from elphel_host.mfsr.scale import check_scale
from elphel_host.mfsr.solve import Geometry, SolveOptions, fit_noise, solve

F32 = NDArray[np.float32]
Shifts = Sequence[tuple[float, float]]

# the blur search runs on a central window: its cost does not grow with the frame size
_PSF_WINDOW = 128
# cross-validation needs a few frames to hold out
_MIN_FRAMES_TO_SEARCH = 5


@dataclass(frozen=True)
class ResolvedPsf:
    """The optics and prior a reconstruction uses, and where they came from (``report``)."""

    optics: Optics
    tau: float
    report: dict[str, Any] = field(default_factory=dict, compare=False)

    def for_colour(self, spec: PsfSpec, colour: int) -> ResolvedPsf:
        """The same with colour ``colour``'s own kernel where ``spec`` gives one."""
        if not isinstance(spec, GivenKernel) or spec.rgb is None:
            return self
        optics = Optics(0.0, spec.rgb[colour], self.optics.prior_sigma)
        return ResolvedPsf(optics, self.tau, self.report)


def given_optics(spec: PsfSpec) -> Optics | None:
    """The optics ``spec`` states (None: to be estimated).

    Raises ValueError for a grid, which is resolved region by region.
    """
    if isinstance(spec, EstimateBlur):
        return None
    if isinstance(spec, NoBlur):
        return NO_OPTICS
    if isinstance(spec, GivenKernel):
        return Optics(kernel=spec.kernel)
    if isinstance(spec, GaussianPsf):
        sigma = spec.sigma_px
        return Optics(sigma) if sigma is not None else Optics(kernel=spec.on_grid(1))
    raise ValueError(
        f"psf {type(spec).__name__}; allowed here: one PSF for the frames (a grid is fused "
        "region by region: elphel_host.mfsr.fuse.fuse_frames)"
    )


def _resolved(optics: Optics, tau: float, source: str, tau_cv: float | None = None) -> ResolvedPsf:
    report = {**optics.to_json(), "source": source}
    if tau_cv is not None:
        report["tau"] = tau_cv
    report["tau_used"] = round(tau, 4)
    return ResolvedPsf(optics, tau, report)


def _blended_tau(default: float, chosen: float | None) -> float:
    """The tau used: halfway (on a log scale) between the default and the cross-validated.

    The cross-validation's tau best predicts LR frames; the HR image is better served by
    a stronger prior, and halfway beat both ends on the benchmark's bursts.
    """
    return default if chosen is None else float(np.sqrt(default * chosen))


def resolve_psf(
    frames: Sequence[F32], shifts: Shifts, geometry: Geometry, config: RobustConfig
) -> ResolvedPsf:
    """``config.psf`` made concrete: the optics and the prior's tau a reconstruction uses.

    Estimated (:class:`EstimateBlur`): a central window is reconstructed without blur to
    refine its shifts and measure its noise, then :func:`~elphel_host.mfsr.psf.estimate_psf`
    searches it. Given optics with ``config.choose_tau`` get the prior's tau
    cross-validated on the same window. Bursts too small for cross-validation (fewer
    than 5 frames) get the given optics, or none, and ``config.tau``.
    """
    if isinstance(config.psf, NoBlur):
        return _resolved(NO_OPTICS, config.tau, "disabled")
    given = given_optics(config.psf)
    if given is not None and not config.choose_tau:
        return _resolved(given, config.tau, "given")
    if len(frames) < _MIN_FRAMES_TO_SEARCH:
        if given is None:
            return _resolved(NO_OPTICS, config.tau, "too few frames")
        return _resolved(given, config.tau, "given")
    crop = central_window([np.asarray(f, np.float32) for f in frames], _PSF_WINDOW)
    start = ResolvedPsf(given or NO_OPTICS, config.tau)
    _, info = reconstruct_resolved(crop, shifts, geometry, start, config)
    refined = [(a, b) for a, b in info["shifts_refined"]]
    where: dict[str, Any] = {
        "scale": int(geometry.scale),
        "aperture": geometry.aperture,
        "origin_shift": geometry.origin_shift,
        "noise_sigma": float(info["noise_sigma"]),
        "window": _PSF_WINDOW,
    }
    if given is not None:
        tau_cv = cross_validated_tau(crop, refined, given, **where)
        return _resolved(given, _blended_tau(config.tau, tau_cv), "given", tau_cv)
    est = estimate_psf(crop, refined, default_tau=config.tau, **where)
    tau = _blended_tau(config.tau, est.tau)
    return ResolvedPsf(est.optics, tau, {**est.to_json(), "tau_used": round(tau, 4)})


def _noise(
    frames: Sequence[F32],
    shifts: Shifts,
    geometry: Geometry,
    psf: ResolvedPsf,
    config: RobustConfig,
) -> tuple[float, str]:
    """The noise that sets the prior's weight and the first clipping level, and its source."""
    if config.noise_sigma is not None:
        return float(config.noise_sigma), "given"
    sigma = estimate_noise(np.asarray(frames[0], dtype=np.float32))
    if not config.fit_noise:
        return sigma, "frame"
    options = SolveOptions(huber=config.huber, pad=config.pad, refine=config.refine)
    fitted = fit_noise(frames, shifts, geometry, psf.optics, tau=psf.tau, options=options)
    # texture only adds to a single frame's estimate: a fit above it went wrong (motion,
    # bad registration), and the frame's estimate is the safer bound
    if fitted is not None and fitted < sigma:
        return fitted, "fit"
    return sigma, "frame"


def _refined_on_window(
    frames: Sequence[F32],
    shifts: Shifts,
    geometry: Geometry,
    psf: ResolvedPsf,
    config: RobustConfig,
    noise: tuple[float, str],
) -> list[tuple[float, float]]:
    """Shifts refined by the solve of a central ``config.refine_window`` window."""
    crop = central_window(frames, config.refine_window)
    fixed = noise[1] in ("given", "fit")  # else the window measures its own
    sigma = noise[0] if fixed else estimate_noise(np.asarray(crop[0], dtype=np.float32))
    options = SolveOptions(config.passes, config.huber, config.pad, True, adapt_noise=not fixed)
    _, info = solve(
        crop, shifts, geometry, psf.optics, tau=psf.tau, noise_sigma=sigma, options=options
    )
    return [(a, b) for a, b in info["shifts_refined"]]


def reconstruct_resolved(
    frames: Sequence[F32],
    shifts: Shifts,
    geometry: Geometry,
    psf: ResolvedPsf,
    config: RobustConfig,
) -> tuple[F32, dict[str, Any]]:
    """:func:`reconstruct` with the PSF already resolved: noise, window refinement, solve."""
    h, w = frames[0].shape
    noise = _noise(frames, shifts, geometry, psf, config)
    # refining shifts needs a determined model: at least one frame per HR unknown
    refine = config.refine and len(frames) >= int(geometry.scale) ** 2
    if refine and config.passes > 0 and max(h, w) > config.refine_window:
        shifts = _refined_on_window(frames, shifts, geometry, psf, config, noise)
        refine = False
    options = SolveOptions(
        config.passes, config.huber, config.pad, refine, adapt_noise=config.noise_sigma is None
    )
    img, info = solve(
        frames, shifts, geometry, psf.optics, tau=psf.tau, noise_sigma=noise[0], options=options
    )
    return img, {**info, "noise_source": noise[1]}


def reconstruct(
    frames: Sequence[F32],
    shifts: Shifts,
    *,
    scale: int,
    aperture: int | None = None,
    origin_shift: tuple[float, float] = (0.0, 0.0),
    config: RobustConfig = DEFAULT_CONFIG,
) -> tuple[F32, dict[str, Any]]:
    """Fuse registered frames onto the reference's grid up-sampled by ``scale``.

    Parameters
    ----------
    frames
        2-D frames of one size; ``frames[0]`` is the reference.
    shifts
        (dy, dx) per frame in LR px (frame k's pixel i sees reference coordinate i + shift).
    scale
        Integer up-sampling factor.
    aperture
        Pixel aperture in HR px (default ``scale``: a fully filled LR pixel).
    origin_shift
        Added to every shift (LR px): moves the output grid, used for Bayer planes.
    config
        Reconstruction options; ``config.psf`` one PSF for the frames (not a grid).

    Returns
    -------
    image, info
        The HR image (float32, input units) and a dict with the noise estimate, the
        regularisation weight, the refined shifts and the PSF used (``psf``).
    """
    if len(shifts) != len(frames):
        raise ValueError(f"len(shifts)={len(shifts)}; allowed: {len(frames)} (one per frame)")
    scale = check_scale(scale, maximum=None)
    h, w = check_frames(frames)
    if min(h, w) < 4:
        raise ValueError(f"frame size {h}x{w}; allowed: at least 4x4")
    if isinstance(config.psf, GivenGrid):
        given_optics(config.psf)  # raises: a grid is fused region by region
    geometry = Geometry(int(scale), aperture, origin_shift)
    psf = resolve_psf(frames, shifts, geometry, config)
    img, info = reconstruct_resolved(frames, shifts, geometry, psf, config)
    return img, {**info, "psf": psf.report}
