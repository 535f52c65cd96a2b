"""``robust`` fusion: noise and shifts measured on windows, the PSF resolved, one solve.

:func:`reconstruct` is the orchestrator; a Bayer burst's colour planes go through the same
steps (:func:`reconstruct_planes`), measured once on one plane (green) and solved together:

1. :func:`measure`: the noise, given or the smaller of a single frame's estimate and a
   fit of the burst (:func:`~elphel_host.mfsr.solve.fit_noise`; a single frame cannot
   tell fine, aliased texture from noise), per plane; and for frames larger than
   ``refine_window`` the shifts, refined by the solve of a central window of that size
   (same model, exact, a fraction of the work), with the given optics or none.
2. :func:`resolve_psf` turns the configured :data:`~elphel_host.mfsr.psf_spec.PsfSpec`
   into concrete optics and a prior's tau: given optics as they are, or the blur
   estimated (:mod:`elphel_host.mfsr.psf`) on a 128 px central window with the measured
   noise and refined shifts (smaller frames have theirs refined on that window first);
   a given PSF gets its prior's tau cross-validated the same way.
3. :func:`~elphel_host.mfsr.solve.solve_planes` with those optics, tau, noise and shifts;
   at full size the robust pass only clips outliers when the shifts are already refined.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
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
from elphel_host.mfsr.solve import (
    Geometry,
    Plane,
    SolveOptions,
    fit_noise,
    measure_passes,
    solve_planes,
)

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


@dataclass(frozen=True)
class Measured:
    """What the windows of a burst measured before the full-size solve.

    Attributes
    ----------
    noise
        Per plane: the noise (input units) and where it came from (``given``, ``fit``,
        ``frame``).
    shifts
        Per plane: the shifts the solve uses (refined on a window when ``refined``).
    refined
        The shifts were refined on a window: the full-size passes only clip outliers.
    window_noise
        The key plane's noise as that window's residuals measured it (the noise the blur
        search scores with); without a window, its ``noise``.
    """

    noise: list[tuple[float, str]]
    shifts: list[list[tuple[float, float]]]
    refined: bool
    window_noise: float


Planes = Sequence[tuple[Sequence[F32], Shifts]]
Spread = Callable[[list[tuple[float, float]]], list[list[tuple[float, float]]]]


def _start(config: RobustConfig) -> ResolvedPsf:
    """The optics known before any search: the given ones, or none; the default tau."""
    return ResolvedPsf(given_optics(config.psf) or NO_OPTICS, config.tau)


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
    window: int,
) -> tuple[list[tuple[float, float]], float]:
    """Shifts refined by the solve of a central ``window`` x ``window`` window.

    Returns them with the noise the window's residuals measured (``noise`` when given).
    """
    crop = central_window(frames, window)
    fixed = noise[1] in ("given", "fit")  # else the window measures its own
    sigma = noise[0] if fixed else estimate_noise(np.asarray(crop[0], dtype=np.float32))
    # the passes refine the shifts before they re-measure the noise: it changes only the
    # window's own image, and is the noise the blur search scores its candidates with
    adapt = config.noise_sigma is None
    options = SolveOptions(config.passes, config.huber, config.pad, True, adapt_noise=adapt)
    info = measure_passes(
        crop, shifts, geometry, psf.optics, tau=psf.tau, noise_sigma=sigma, options=options
    )
    return [(a, b) for a, b in info["shifts_refined"]], float(info["noise_sigma"])


def _can_refine(n_frames: int, geometry: Geometry, config: RobustConfig) -> bool:
    # refining shifts needs a determined model: at least one frame per HR unknown
    return config.refine and config.passes > 0 and n_frames >= int(geometry.scale) ** 2


def measure(
    planes: Planes,
    geometry: Geometry,
    config: RobustConfig,
    start: ResolvedPsf,
    *,
    key: int = 0,
    spread: Spread | None = None,
) -> Measured:
    """Each plane's noise, and the shifts refined once on plane ``key``'s window.

    ``start`` holds the optics and tau the windows are solved with; ``spread`` turns
    plane ``key``'s refined shifts into every plane's (default: there is one plane).
    Frames of at most ``config.refine_window`` px keep their shifts (the full-size
    passes refine them).
    """
    noise = [_noise(f, s, geometry, start, config) for f, s in planes]
    frames, shifts = planes[key]
    h, w = frames[0].shape
    if max(h, w) > config.refine_window and _can_refine(len(frames), geometry, config):
        refined, window_noise = _refined_on_window(
            frames, shifts, geometry, start, config, noise[key], config.refine_window
        )
        every = spread(refined) if spread is not None else [refined]
        return Measured(noise, every, True, window_noise)
    return Measured(noise, [[(a, b) for a, b in s] for _, s in planes], False, noise[key][0])


def _searches(config: RobustConfig, n_frames: int) -> bool:
    """Whether the PSF's resolution looks at the burst (an estimate or tau's choice)."""
    if isinstance(config.psf, NoBlur) or n_frames < _MIN_FRAMES_TO_SEARCH:
        return False
    return given_optics(config.psf) is None or config.choose_tau


def resolve_psf(
    frames: Sequence[F32],
    shifts: Shifts,
    geometry: Geometry,
    config: RobustConfig,
    noise: tuple[float, str],
    *,
    refined: float | None,
) -> ResolvedPsf:
    """``config.psf`` made concrete: the optics and the prior's tau a reconstruction uses.

    Estimated (:class:`EstimateBlur`): :func:`~elphel_host.mfsr.psf.estimate_psf`
    searches a central window with the shifts, refined on that window first unless
    ``refined`` (then the noise that refinement measured), and the noise that window's
    residuals give (``noise`` is the burst's). Given optics with ``config.choose_tau`` get the
    prior's tau cross-validated on the same window. Bursts too small for
    cross-validation (fewer than 5 frames) get the given optics, or none, and
    ``config.tau``.
    """
    if isinstance(config.psf, NoBlur):
        return _resolved(NO_OPTICS, config.tau, "disabled")
    given = given_optics(config.psf)
    if not _searches(config, len(frames)):
        if given is None:
            return _resolved(NO_OPTICS, config.tau, "too few frames")
        return _resolved(given, config.tau, "given")
    crop = central_window([np.asarray(f, np.float32) for f in frames], _PSF_WINDOW)
    sigma = refined
    if sigma is None:
        if _can_refine(len(frames), geometry, config):
            window = (crop, shifts, geometry, _start(config), config, noise, _PSF_WINDOW)
            shifts, sigma = _refined_on_window(*window)
        else:
            sigma = noise[0]
    where: dict[str, Any] = {
        "scale": int(geometry.scale),
        "aperture": geometry.aperture,
        "origin_shift": geometry.origin_shift,
        "noise_sigma": float(sigma),
        "window": _PSF_WINDOW,
    }
    if given is not None:
        tau_cv = cross_validated_tau(crop, shifts, given, **where)
        return _resolved(given, _blended_tau(config.tau, tau_cv), "given", tau_cv)
    est = estimate_psf(crop, shifts, default_tau=config.tau, **where)
    tau = _blended_tau(config.tau, est.tau)
    return ResolvedPsf(est.optics, tau, {**est.to_json(), "tau_used": round(tau, 4)})


def solve_measured(
    planes: Planes,
    measured: Measured,
    geometry: Geometry,
    psfs: Sequence[ResolvedPsf],
    config: RobustConfig,
) -> list[tuple[F32, dict[str, Any]]]:
    """The planes solved together with their measured noise and shifts, and their PSFs."""
    options = SolveOptions(
        config.passes,
        config.huber,
        config.pad,
        config.refine and not measured.refined,
        adapt_noise=config.noise_sigma is None,
    )
    todo = [
        Plane(frames, shifts, psf.optics, noise[0])
        for (frames, _), shifts, psf, noise in zip(
            planes, measured.shifts, psfs, measured.noise, strict=True
        )
    ]
    out = solve_planes(todo, geometry, tau=psfs[0].tau, options=options)
    return [
        (img, {**info, "noise_source": noise[1]})
        for (img, info), noise in zip(out, measured.noise, strict=True)
    ]


def reconstruct_resolved(
    frames: Sequence[F32],
    shifts: Shifts,
    geometry: Geometry,
    psf: ResolvedPsf,
    config: RobustConfig,
) -> tuple[F32, dict[str, Any]]:
    """:func:`reconstruct` with the PSF already resolved: noise, window refinement, solve."""
    measured = measure([(frames, shifts)], geometry, config, psf)
    return solve_measured([(frames, shifts)], measured, geometry, [psf], config)[0]


def reconstruct_planes(
    planes: Planes,
    geometry: Geometry,
    config: RobustConfig,
    *,
    key: int = 0,
    spread: Spread | None = None,
    colour_psf: Callable[[ResolvedPsf, int], ResolvedPsf] | None = None,
) -> tuple[list[tuple[F32, dict[str, Any]]], ResolvedPsf]:
    """Planes of one burst measured and their PSF resolved on plane ``key``, solved together.

    ``spread`` turns plane ``key``'s refined shifts into every plane's; ``colour_psf``
    gives plane c its own PSF from the resolved one (default: the same for all).
    Returns each plane's image and details, and the resolved PSF.
    """
    measured = measure(planes, geometry, config, _start(config), key=key, spread=spread)
    psf = resolve_psf(
        planes[key][0],
        measured.shifts[key],
        geometry,
        config,
        measured.noise[key],
        refined=measured.window_noise if measured.refined else None,
    )
    psfs = [psf if colour_psf is None else colour_psf(psf, c) for c in range(len(planes))]
    return solve_measured(planes, measured, geometry, psfs, config), psf


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
    [(img, info)], psf = reconstruct_planes([(frames, shifts)], geometry, config)
    return img, {**info, "psf": psf.report}
