"""The robust reconstruction's solve: registered frames, optics, noise in; HR image out.

Steps (see :mod:`elphel_host.mfsr.forward` for the model and the solver):

1. Each frame is moved by the integer part of its shift onto the reference grid; the
   pixels it does not cover are marked invalid (filled, for the first solve only, with the
   reference's own pixels). Frames are mirror-padded so that the periodic Fourier model
   has no seam inside the image.
2. Least-squares solve with a gradient prior, weight ``(sigma / tau)^2``: sigma is the
   noise, tau the expected HR gradient (a fraction of the range).
3. Robust passes: every frame's shift is refined against the model (this removes the
   aliasing bias of LR registration), its residual clipped at ``huber * sigma`` (Huber
   regression by pseudo-data; invalid pixels take the prediction), and the system solved
   again.

:func:`fit_noise` measures a burst's noise with the same solve on a central window.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.fft as sfft
from numpy.typing import NDArray

from elphel_host.mfsr.forward import C64, ForwardModel, FourierSolver
from elphel_host.mfsr.frames import aligned, central_window, estimate_noise, padded
from elphel_host.mfsr.psf import Optics
from elphel_host.mfsr.refine import ModelSpectra, refine_and_pseudo
from elphel_host.parallel import parallel_map

F32 = NDArray[np.float32]
Shifts = Sequence[tuple[float, float]]

_CHUNK = 4  # frames a step of the solver takes at once


@dataclass(frozen=True)
class Geometry:
    """How frames map onto the HR grid: scale, pixel aperture (HR px), grid offset (LR px)."""

    scale: int
    aperture: int | None = None
    origin_shift: tuple[float, float] = (0.0, 0.0)


@dataclass(frozen=True)
class SolveOptions:
    """The solve's own options (see :class:`~elphel_host.mfsr.robust_config.RobustConfig`).

    ``adapt_noise``: the robust passes may replace the noise by the residuals' spread.
    """

    passes: int = 1
    huber: float = 3.0
    pad: int = 16
    refine: bool = True
    adapt_noise: bool = True


def _pads(h: int, w: int, pad: int) -> tuple[tuple[int, int], tuple[int, int, int, int]]:
    """FFT-friendly padded size and the pads (top, bottom, left, right) of an h x w frame."""
    p = min(pad, h - 1, w - 1)
    ny, nx = sfft.next_fast_len(h + 2 * p), sfft.next_fast_len(w + 2 * p)
    pads = (p, ny - h - p, p, nx - w - p)
    if pads[1] >= h or pads[3] >= w:  # reflection needs the frame to be larger than the pad
        return (h + 2 * p, w + 2 * p), (p, p, p, p)
    return (ny, nx), pads


class _Frames:
    """The burst's frames aligned by their integer shifts and padded, kept for the passes.

    The robust passes need every padded frame again: kept (memory grows by the input
    size, N LR frames, not by N x the output size).
    """

    def __init__(self, frames: Sequence[F32], n_int: NDArray[np.int_], pads: Any, keep: bool):
        self.frames, self.n_int, self.pads, self.keep = frames, n_int, pads, keep
        self.ref = np.asarray(frames[0], dtype=np.float32)
        self.kept: dict[int, tuple[F32, NDArray[np.bool_]]] = {}

    def __call__(self, k: int) -> tuple[F32, NDArray[np.bool_]]:
        if k in self.kept:
            return self.kept[k]
        shift = (int(self.n_int[k, 0]), int(self.n_int[k, 1]))
        f, v = aligned(np.asarray(self.frames[k], np.float32), self.ref, shift)
        out = (
            np.asarray(padded(f, self.pads, mode="reflect"), np.float32),
            np.asarray(padded(v, self.pads, mode="zero"), bool),
        )
        if self.keep:
            self.kept[k] = out
        return out


def _robust_pass(
    solver: FourierSolver,
    spectra: ModelSpectra,
    frames: _Frames,
    sigma: float,
    opts: SolveOptions,
) -> list[float]:
    """One robust pass: each frame refined and clipped against the model, re-added; MADs."""
    solver.reset()
    mads: list[float] = []

    def step(k: int) -> tuple[F32, tuple[float, float], float]:
        f, v = frames(k)
        pseudo, dt, r = refine_and_pseudo(
            solver, spectra, k, f, v, huber=opts.huber, sigma=sigma, refine=opts.refine, workers=1
        )
        sub = np.abs(r[::3, ::3][v[::3, ::3]])
        return pseudo, dt, float(np.median(sub)) if sub.size else 0.0

    # A frame's step reads only its own shift and the model of the previous solve, so the
    # frames of a chunk run on every core; they are added in chunks (one matrix product
    # each) once their refined shifts are in.
    ks = list(range(len(frames.frames)))
    for start in range(0, len(ks), _CHUNK):
        chunk = ks[start : start + _CHUNK]
        steps = parallel_map(step, chunk)
        for k, (_, dt, mad) in zip(chunk, steps, strict=True):
            mads.append(mad)
            if dt[0] or dt[1]:
                solver.move(k, dt)
        solver.add_frames(chunk, [pseudo for pseudo, _, _ in steps])
    return mads


def _range(ref: F32) -> float:
    """The reference's value range (0.1 to 99.9 percentile): the unit of tau."""
    step = max(1, int(np.sqrt(ref.size / 250_000)))  # a quarter-million samples suffice
    lo, hi = np.percentile(ref[::step, ::step], [0.1, 99.9])
    return max(float(hi - lo), 1e-6)


def solve(
    frames: Sequence[F32],
    shifts: Shifts,
    geometry: Geometry,
    optics: Optics,
    *,
    tau: float,
    noise_sigma: float,
    options: SolveOptions,
) -> tuple[F32, dict[str, Any]]:
    """Fuse registered frames with known optics, prior and noise (one solve + robust passes).

    Parameters
    ----------
    frames, shifts
        As for :func:`elphel_host.mfsr.robust.reconstruct` (checked there).
    geometry
        Scale, pixel aperture and the output grid's offset.
    optics
        The blur deconvolved and the prior's shape.
    tau
        The prior's expected HR gradient (fraction of the reference's range).
    noise_sigma
        Noise standard deviation (input units): the prior's weight and the first clipping.
    options
        Passes, clipping, padding, refinement, whether the passes may re-measure the noise.

    Returns
    -------
    image, info
        The HR image (float32) and ``noise_sigma`` (the one that set the prior's weight),
        ``lambda`` and ``shifts_refined``.
    """
    scale = int(geometry.scale)
    h, w = frames[0].shape
    sh = np.asarray(shifts, np.float64) + np.asarray(geometry.origin_shift, np.float64)
    n_int = np.rint(sh).astype(int)
    lr_shape, pads = _pads(h, w, options.pad)
    aperture = int(geometry.aperture or scale)
    model = ForwardModel(
        lr_shape, scale, aperture, optics.blur_sigma, optics.kernel, optics.prior_sigma
    )
    source = _Frames(frames, n_int, pads, keep=options.passes > 0)
    span = _range(source.ref)
    tau_dn, sigma, noise = tau * span, noise_sigma, noise_sigma
    solver = FourierSolver(
        model, [tuple(v) for v in sh - n_int], lam=max((sigma / tau_dn) ** 2, 1e-6)
    )
    t0_start = solver.t[0].copy()
    for start in range(0, len(frames), _CHUNK):
        chunk = list(range(start, min(start + _CHUNK, len(frames))))
        solver.add_frames(chunk, [source(k)[0] for k in chunk])
    X = solver.solve()
    s2 = scale * scale
    dof = max(1.0 - s2 / len(frames), 0.25)
    for _ in range(options.passes):
        spectra = ModelSpectra(solver, X)
        del X
        mads = _robust_pass(solver, spectra, source, sigma, options)
        del spectra
        if options.adapt_noise:
            # the residual spread sets the clipping level only: with few frames per
            # unknown it under-estimates the noise, so it must not weaken the prior
            sigma = max(1.4826 * float(np.median(mads)) / np.sqrt(dof), 1e-6 * span)
            if len(frames) >= 2 * s2:  # enough frames per unknown for the estimate to hold
                noise = sigma
                solver.lam = max((noise / tau_dn) ** 2, 1e-6)
        X = solver.solve()
    return _on_reference_grid(solver, X, t0_start, n_int, geometry, (h, w), pads[0], noise)


def _on_reference_grid(
    solver: FourierSolver,
    X: C64,
    t0_start: NDArray[np.float64],
    n_int: NDArray[np.int_],
    geometry: Geometry,
    shape: tuple[int, int],
    p: int,
    noise: float,
) -> tuple[F32, dict[str, Any]]:
    """The solution cropped to the frames' area, moved back onto the reference's grid.

    The shifts are refined jointly, the reference's too: the common part of the
    refinements is a drift of the model's grid away from the reference frame (a global
    shift is invisible to the data).
    """
    scale = int(geometry.scale)
    h, w = shape
    drift = solver.t[0] - t0_start
    img = solver.to_image(X, shift_hr=(float(drift[0]), float(drift[1])))
    y0 = x0 = p * scale
    out = np.ascontiguousarray(img[y0 : y0 + h * scale, x0 : x0 + w * scale])
    refined = solver.shifts_lr() - drift / scale + n_int - np.asarray(geometry.origin_shift)
    info = {
        "noise_sigma": noise,
        "lambda": solver.lam,
        "shifts_refined": [[float(a), float(b)] for a, b in refined],
    }
    return out, info


# The noise fit: a central window has samples enough for a spread estimate, and a prior
# 16^2 times weaker than the reconstruction's only keeps the frequencies that no frame
# observes bounded (it smooths nothing the data determine).
_FIT_WINDOW = 256
_FIT_TAU_FACTOR = 16.0


def fit_noise(
    frames: Sequence[F32],
    shifts: Shifts,
    geometry: Geometry,
    optics: Optics,
    *,
    tau: float,
    options: SolveOptions,
) -> float | None:
    """Noise standard deviation measured from a registered burst.

    Single-frame estimates (:func:`~elphel_host.mfsr.frames.estimate_noise`) take whatever
    a Laplacian sees as noise, fine texture included: on an image with detail near its
    Nyquist frequency, and above all on one colour plane of a Bayer mosaic (samples two
    pixels apart, heavily aliased), they measure mostly texture. A burst whose frames
    outnumber the unknowns predicts each frame from the others: the residual of a
    least-squares fit with a weak prior, divided by the degrees of freedom left
    (``1 - s^2 / K`` for K frames at scale s), is the noise.

    The fit uses the largest scale ``s <= scale`` with at least ``2 s^2`` frames (and the
    same pixel aperture in LR units), a central window of up to 256 px and :func:`solve`
    with one pass, shifts refined, a 256 times weaker prior; residuals are measured by
    their median.

    Returns
    -------
    float or None
        The noise standard deviation in input units; None when no scale >= 2 has enough
        frames.
    """
    k, scale = len(frames), int(geometry.scale)
    ap = int(geometry.aperture or scale)
    fit_scale = next(
        (s for s in range(scale, 1, -1) if k >= 2 * s * s and (ap * s) % scale == 0), None
    )
    if fit_scale is None:
        return None
    crop = central_window(frames, _FIT_WINDOW)
    fit = Geometry(fit_scale, ap * fit_scale // scale, geometry.origin_shift)
    _, info = solve(
        crop,
        shifts,
        fit,
        optics.at_scale(fit_scale / scale),  # in the fit's HR px
        tau=tau * _FIT_TAU_FACTOR,
        noise_sigma=estimate_noise(np.asarray(crop[0], np.float32)),
        options=SolveOptions(
            passes=1, huber=options.huber, pad=options.pad, refine=options.refine, adapt_noise=True
        ),
    )
    return float(info["noise_sigma"])
