"""``robust`` fusion: registered frames -> forward-model reconstruction with outlier rejection.

Steps (see :mod:`elphel_host.mfsr.forward` for the model and the solver,
:mod:`elphel_host.mfsr.robust_config` for the options):

1. Each frame is moved by the integer part of its shift onto the reference grid; the
   pixels it does not cover are marked invalid (filled, for the first solve only, with the
   reference's own pixels). Frames are mirror-padded so that the
   periodic Fourier model has no seam inside the image.
2. Least-squares solve with a gradient prior, weight ``(sigma / tau)^2``: sigma is the
   noise, tau the expected HR gradient (a fraction of the range). With enough frames the
   noise is measured from the burst itself (:func:`fit_noise`); a single frame cannot tell
   fine, aliased texture from noise.
3. Robust passes: every frame's shift is refined against the model (this removes the
   aliasing bias of LR registration), its residual clipped at ``huber * sigma`` (Huber
   regression by pseudo-data; invalid pixels take the prediction), and the system solved
   again.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
import scipy.fft as sfft
from numpy.typing import NDArray

from elphel_host.mfsr.forward import ForwardModel, FourierSolver
from elphel_host.mfsr.frames import (
    aligned,
    central_window,
    check_frames,
    estimate_noise,
    padded,
)
from elphel_host.mfsr.psf import PsfEstimate, estimate_psf
from elphel_host.mfsr.refine import ModelSpectra, refine_and_pseudo
from elphel_host.mfsr.robust_config import DEFAULT_CONFIG, RobustConfig
from elphel_host.mfsr.scale import check_scale
from elphel_host.parallel import parallel_map

F32 = NDArray[np.float32]


# The noise fit: a central window has samples enough for a spread estimate, and a prior
# 16^2 times weaker than the reconstruction's only keeps the frequencies that no frame
# observes bounded (it smooths nothing the data determine).
_FIT_WINDOW = 256
_FIT_TAU_FACTOR = 16.0


def fit_noise(
    frames: Sequence[F32],
    shifts: Sequence[tuple[float, float]],
    *,
    scale: int,
    aperture: int | None = None,
    origin_shift: tuple[float, float] = (0.0, 0.0),
    config: RobustConfig = DEFAULT_CONFIG,
) -> float | None:
    """Noise standard deviation measured from a registered burst.

    Single-frame estimates (:func:`estimate_noise`) take whatever a Laplacian sees as
    noise, fine texture included: on an image with detail near its Nyquist frequency, and
    above all on one colour plane of a Bayer mosaic (samples two pixels apart, heavily
    aliased), they measure mostly texture. A burst whose frames outnumber the unknowns
    predicts each frame from the others: the residual of a least-squares fit with a weak
    prior, divided by the degrees of freedom left (``1 - s^2 / K`` for K frames at scale s),
    is the noise.

    The fit uses the largest scale ``s <= scale`` with at least ``2 s^2`` frames (and the
    same pixel aperture in LR units), a central window of up to 256 px and the model of
    :func:`reconstruct`, shifts refined; residuals are measured by their median.

    Parameters
    ----------
    frames, shifts, scale, aperture, origin_shift
        As for :func:`reconstruct`.
    config
        Reconstruction options (the fit uses a 256 times weaker prior, one pass).

    Returns
    -------
    float or None
        The noise standard deviation in input units; None when no scale >= 2 has enough
        frames.
    """
    k = len(frames)
    ap = int(aperture or scale)
    fit_scale = next(
        (s for s in range(int(scale), 1, -1) if k >= 2 * s * s and (ap * s) % scale == 0), None
    )
    if fit_scale is None:
        return None
    crop = central_window(frames, _FIT_WINDOW)
    wy, wx = crop[0].shape
    _, info = reconstruct(
        crop,
        shifts,
        scale=fit_scale,
        aperture=ap * fit_scale // scale,
        origin_shift=origin_shift,
        config=replace(
            config,
            passes=1,
            tau=config.tau * _FIT_TAU_FACTOR,
            blur_sigma=config.blur_sigma * fit_scale / int(scale),  # in the fit's HR px
            prior_sigma=config.prior_sigma * fit_scale / int(scale),
            psf_kernel=config.psf_kernel if fit_scale == int(scale) else None,
            estimate_psf=False,
            noise_sigma=None,
            fit_noise=False,
            refine_window=max(wy, wx, 32),
        ),
    )
    return float(info["noise_sigma"])


# the blur search runs on a central window: its cost does not grow with the frame size
_PSF_WINDOW = 128


def psf_for(
    frames: Sequence[F32],
    shifts: Sequence[tuple[float, float]],
    *,
    scale: int,
    aperture: int | None = None,
    origin_shift: tuple[float, float] = (0.0, 0.0),
    config: RobustConfig = DEFAULT_CONFIG,
) -> PsfEstimate:
    """The PSF a reconstruction with ``config`` uses: given, disabled, or estimated.

    Estimated (``config.estimate_psf`` and no ``blur_sigma``, ``prior_sigma`` or
    ``psf_kernel`` given): the shifts are first refined and the noise fitted by a
    reconstruction of a central window, then :func:`elphel_host.mfsr.psf.estimate_psf`
    searches that window. Given optics with ``config.estimate_psf`` (the default) get the
    prior's tau searched the same way, the optics fixed. Bursts too small for
    cross-validation (fewer than 5 frames) get no blur and no search.
    """
    given: PsfEstimate | None = None
    if config.psf_kernel is not None:
        given = PsfEstimate("kernel", 0.0, "given", kernel=config.psf_kernel)
    elif config.blur_sigma > 0 or config.prior_sigma > 0:
        model = "gaussian" if config.blur_sigma > 0 else "none"
        given = PsfEstimate(model, config.blur_sigma, "given", prior_sigma=config.prior_sigma)
    if not config.estimate_psf or len(frames) < 5:
        reason = "disabled" if not config.estimate_psf else "too few frames"
        return given or PsfEstimate("none", 0.0, reason)
    crop = central_window([np.asarray(f, np.float32) for f in frames], _PSF_WINDOW)
    _, info = reconstruct(
        crop,
        shifts,
        scale=scale,
        aperture=aperture,
        origin_shift=origin_shift,
        config=replace(config, estimate_psf=False, refine_window=_PSF_WINDOW),
    )
    return estimate_psf(
        crop,
        [(a, b) for a, b in info["shifts_refined"]],
        scale=scale,
        aperture=aperture,
        origin_shift=origin_shift,
        noise_sigma=float(info["noise_sigma"]),
        window=_PSF_WINDOW,
        default_tau=config.tau,
        given=given,
    )


def with_psf(config: RobustConfig, psf: PsfEstimate) -> RobustConfig:
    """``config`` reconstructing with ``psf`` (itself when there is nothing to apply).

    Nothing to apply: disabled, too few frames, a kernel the fit could not use. The
    cross-validation's tau best predicts LR frames; the HR image is better served by a
    stronger prior: tau halfway (on a log scale) between the default and that choice,
    which beat both ends on the benchmark's bursts when it was chosen (docs/mfsr.md).
    """
    if psf.source != "estimated" and psf.tau is None:  # nothing found to apply
        return config
    tau = config.tau if psf.tau is None else float(np.sqrt(config.tau * psf.tau))
    if psf.source == "given":  # the optics are config's own
        return replace(config, tau=tau, estimate_psf=False)
    return replace(
        config,
        blur_sigma=psf.sigma,
        prior_sigma=psf.prior_sigma,
        tau=tau,
        estimate_psf=False,
    )


def reconstruct(
    frames: Sequence[F32],
    shifts: Sequence[tuple[float, float]],
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
        Reconstruction options.

    Returns
    -------
    image, info
        The HR image (float32, input units) and a dict with the noise estimate, the
        regularisation weight and the refined shifts.
    """
    if len(shifts) != len(frames):
        raise ValueError(f"len(shifts)={len(shifts)}; allowed: {len(frames)} (one per frame)")
    scale = check_scale(scale, maximum=None)
    h, w = check_frames(frames)
    if min(h, w) < 4:
        raise ValueError(f"frame size {h}x{w}; allowed: at least 4x4")
    psf = psf_for(
        frames,
        shifts,
        scale=int(scale),
        aperture=aperture,
        origin_shift=origin_shift,
        config=config,
    )
    config = with_psf(config, psf)
    ref = np.asarray(frames[0], dtype=np.float32)
    # the noise sets the prior's weight and the first clipping level
    if config.noise_sigma is not None:
        sigma, source = float(config.noise_sigma), "given"
    else:
        sigma, source = estimate_noise(ref), "frame"
        fitted = (
            fit_noise(
                frames,
                shifts,
                scale=int(scale),
                aperture=aperture,
                origin_shift=origin_shift,
                config=config,
            )
            if config.fit_noise
            else None
        )
        # texture only adds to a single frame's estimate: a fit above it went wrong
        # (motion, bad registration), and the frame's estimate is the safer bound
        if fitted is not None and fitted < sigma:
            sigma, source = fitted, "fit"
    # refining shifts needs a determined model: at least one frame per HR unknown
    refine_here = config.refine and len(frames) >= scale * scale
    if refine_here and config.passes > 0 and max(h, w) > config.refine_window:
        # shifts are refined on a central window (same model, exact, 1/10 of the work);
        # the full-size passes then only clip outliers
        crop = central_window(frames, config.refine_window)
        _, cinfo = reconstruct(
            crop,
            shifts,
            scale=scale,
            aperture=aperture,
            origin_shift=origin_shift,
            config=replace(
                config,
                refine_window=max(h, w),
                noise_sigma=sigma if source == "fit" else config.noise_sigma,
                fit_noise=False,
            ),
        )
        shifts = [(a, b) for a, b in cinfo["shifts_refined"]]
        refine_here = False
    sh = np.asarray(shifts, dtype=np.float64) + np.asarray(origin_shift, dtype=np.float64)
    n_int = np.rint(sh).astype(int)
    frac = sh - n_int
    p = min(config.pad, h - 1, w - 1)
    ny, nx = sfft.next_fast_len(h + 2 * p), sfft.next_fast_len(w + 2 * p)
    pads = (p, ny - h - p, p, nx - w - p)
    if pads[1] >= h or pads[3] >= w:  # reflection needs the frame to be larger than the pad
        ny, nx = h + 2 * p, w + 2 * p
        pads = (p, p, p, p)
    model = ForwardModel(
        (ny, nx),
        int(scale),
        int(aperture or scale),
        config.blur_sigma,
        config.psf_kernel,
        config.prior_sigma,
    )
    step = max(1, int(np.sqrt(ref.size / 250_000)))  # a quarter-million samples suffice
    lo, hi = np.percentile(ref[::step, ::step], [0.1, 99.9])
    span = max(float(hi - lo), 1e-6)
    tau = config.tau * span
    noise = sigma
    lam = max((sigma / tau) ** 2, 1e-6)
    solver = FourierSolver(model, [tuple(v) for v in frac], lam=lam)
    t0_start = solver.t[0].copy()

    # The robust passes need every padded frame again: kept (memory grows by the input
    # size, N LR frames, not by N x the output size).
    kept: dict[int, tuple[F32, NDArray[np.bool_]]] = {}

    def frame_k(k: int) -> tuple[F32, NDArray[np.bool_]]:
        if k in kept:
            return kept[k]
        f, v = aligned(
            np.asarray(frames[k], np.float32),
            ref,
            (int(n_int[k, 0]), int(n_int[k, 1])),
        )
        out = (
            np.asarray(padded(f, pads, mode="reflect"), np.float32),
            np.asarray(padded(v, pads, mode="zero"), bool),
        )
        if config.passes:
            kept[k] = out
        return out

    ks = list(range(len(frames)))
    for start in range(0, len(ks), 4):
        chunk = ks[start : start + 4]
        solver.add_frames(chunk, [frame_k(k)[0] for k in chunk])
    X = solver.solve()
    k_frames, s2 = len(frames), scale * scale
    dof = max(1.0 - s2 / k_frames, 0.25)
    for _ in range(config.passes):
        spectra = ModelSpectra(solver, X)
        del X
        solver.reset()
        mads: list[float] = []

        def robust_step(
            k: int, spectra: ModelSpectra = spectra, sigma: float = sigma
        ) -> tuple[F32, tuple[float, float], float]:
            f, v = frame_k(k)
            pseudo, dt, r = refine_and_pseudo(
                solver,
                spectra,
                k,
                f,
                v,
                huber=config.huber,
                sigma=sigma,
                refine=refine_here,
                workers=1,
            )
            sub = np.abs(r[::3, ::3][v[::3, ::3]])
            return pseudo, dt, float(np.median(sub)) if sub.size else 0.0

        # A frame's step reads only its own shift and the model of the previous solve, so
        # the frames of a chunk run on every core; they are added in chunks (one matrix
        # product each) once their refined shifts are in.
        for start in range(0, len(ks), 4):
            chunk = ks[start : start + 4]
            steps = parallel_map(robust_step, chunk)
            for k, (_, dt, mad) in zip(chunk, steps, strict=True):
                mads.append(mad)
                if dt[0] or dt[1]:
                    solver.move(k, dt)
            solver.add_frames(chunk, [pseudo for pseudo, _, _ in steps])
        if config.noise_sigma is None:
            # the residual spread sets the clipping level only: with few frames per
            # unknown it under-estimates the noise, so it must not weaken the prior
            sigma = max(1.4826 * float(np.median(mads)) / np.sqrt(dof), 1e-6 * span)
            if k_frames >= 2 * s2:  # enough frames per unknown for the estimate to hold
                noise = sigma
                solver.lam = max((noise / tau) ** 2, 1e-6)
        del spectra
        X = solver.solve()
    # The shifts are refined jointly, the reference's too: the common part of the
    # refinements is a drift of the model's grid away from the reference frame (a global
    # shift is invisible to the data); move the image back onto the reference's grid.
    drift = solver.t[0] - t0_start
    img = solver.to_image(X, shift_hr=(float(drift[0]), float(drift[1])))
    y0, x0 = p * scale, p * scale
    out = np.ascontiguousarray(img[y0 : y0 + h * scale, x0 : x0 + w * scale])
    refined = solver.shifts_lr() - drift / scale + n_int - np.asarray(origin_shift)
    info = {
        "noise_sigma": noise,  # the one that set the prior's weight
        "noise_source": source,
        "lambda": solver.lam,
        "shifts_refined": [[float(a), float(b)] for a, b in refined],
    }
    info["psf"] = {**psf.to_json(), "tau_used": round(config.tau, 4)}
    return out, info
