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

:func:`solve_planes` solves several sets of frames on one grid together (a Bayer burst's
colour planes): each set keeps its own frames, shifts, optics and noise, and their block
systems are factored in one batched pass (:func:`~elphel_host.mfsr.forward.solve_joint`).
:func:`fit_noise` measures a burst's noise with the same solve on a central window.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import scipy.fft as sfft
from numpy.typing import NDArray

from elphel_host.mfsr.forward import C64, ForwardModel, FourierSolver, solve_joint
from elphel_host.mfsr.frames import central_window, estimate_noise
from elphel_host.mfsr.kernels import fill_padded
from elphel_host.mfsr.psf import Optics
from elphel_host.mfsr.refine import ModelSpectra, PaddedFrame, refine_and_pseudo
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
    """The burst's frames on the solver's padded grid, each moved by its integer shift.

    A frame's padded copy is made only for its transform, in one of the work frames
    (:meth:`work`, reused for every chunk of frames); the robust passes read the frames
    themselves where they cover the grid (:meth:`placed`).
    """

    def __init__(
        self,
        frames: Sequence[F32],
        n_int: NDArray[np.int_],
        lr_shape: tuple[int, int],
        pads: tuple[int, int, int, int],
    ):
        self.frames = [np.ascontiguousarray(f, np.float32) for f in frames]
        self.ref = self.frames[0]
        self.n_int, self.lr_shape, self.pads = n_int, lr_shape, pads
        self._work: F32 | None = None

    def work(self, n: int) -> list[F32]:
        """``n`` (at most a chunk's) float32 frames of the padded size, reused by every call."""
        if self._work is None:
            self._work = np.empty((_CHUNK, *self.lr_shape), np.float32)
        return list(self._work[:n])

    def fill(self, k: int, out: F32) -> F32:
        """Frame ``k`` moved onto the reference grid and mirror-padded, in ``out``.

        Where it does not cover the grid, the reference's own pixels (the first solve
        only: the passes replace them by the prediction).
        """
        shift = (int(self.n_int[k, 0]), int(self.n_int[k, 1]))
        fill_padded(out, self.frames[k], self.ref, shift, (self.pads[0], self.pads[2]))
        return out

    def placed(self, k: int) -> PaddedFrame:
        """Frame ``k`` where it covers the padded grid."""
        (h, w), (sy, sx) = self.ref.shape, (int(self.n_int[k, 0]), int(self.n_int[k, 1]))
        top, left = self.pads[0], self.pads[2]
        y0, y1 = max(0, sy), min(h, h + sy)
        x0, x1 = max(0, sx), min(w, w + sx)
        if y1 <= y0 or x1 <= x0:
            return PaddedFrame(self.frames[k], (0, 0), (0, 0, 0, 0))
        valid = (top + y0, top + y1, left + x0, left + x1)
        return PaddedFrame(self.frames[k], (top + sy, left + sx), valid)


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

    def step(job: tuple[int, F32]) -> tuple[tuple[float, float], float]:
        k, out = job
        dt, sub = refine_and_pseudo(
            solver,
            spectra,
            k,
            frames.placed(k),
            out,
            huber=opts.huber,
            sigma=sigma,
            refine=opts.refine,
        )
        return dt, float(np.median(sub)) if sub.size else 0.0

    # A frame's step reads only its own shift and the model of the previous solve, so the
    # frames of a chunk run on every core, each into its work frame; they are added in
    # chunks once their refined shifts are in.
    n = len(frames.frames)
    for start in range(0, n, _CHUNK):
        chunk = list(range(start, min(start + _CHUNK, n)))
        work = frames.work(len(chunk))
        steps = parallel_map(step, list(zip(chunk, work, strict=True)), threads=solver.threads)
        for k, (dt, mad) in zip(chunk, steps, strict=True):
            mads.append(mad)
            if dt[0] or dt[1]:
                solver.move(k, dt)
        solver.add_frames(chunk, work, overwrite=True)
    return mads


def _range(ref: F32) -> float:
    """The reference's value range (0.1 to 99.9 percentile): the unit of tau."""
    step = max(1, int(np.sqrt(ref.size / 250_000)))  # a quarter-million samples suffice
    lo, hi = np.percentile(ref[::step, ::step], [0.1, 99.9])
    return max(float(hi - lo), 1e-6)


@dataclass(frozen=True)
class Plane:
    """One set of registered frames to solve: a mono burst, or one colour of a Bayer burst.

    ``frames`` and ``shifts`` as for :func:`elphel_host.mfsr.robust.reconstruct`;
    ``optics`` the blur deconvolved and the prior's shape; ``noise_sigma`` the noise
    (input units) that sets the prior's weight and the first clipping.
    """

    frames: Sequence[F32]
    shifts: Shifts
    optics: Optics
    noise_sigma: float


class _PlaneSolve:
    """A plane's solver, its frames kept for the passes, and its noise as the passes see it."""

    def __init__(self, plane: Plane, geometry: Geometry, tau: float, opts: SolveOptions):
        scale = int(geometry.scale)
        # refining shifts needs a determined model: at least one frame per HR unknown
        self.opts = replace(opts, refine=opts.refine and len(plane.frames) >= scale * scale)
        h, w = plane.frames[0].shape
        self.shape = (int(h), int(w))
        sh = np.asarray(plane.shifts, np.float64) + np.asarray(geometry.origin_shift, np.float64)
        self.n_int = np.rint(sh).astype(int)
        lr_shape, self.pads = _pads(h, w, opts.pad)
        optics = plane.optics
        model = ForwardModel(
            lr_shape,
            scale,
            int(geometry.aperture or scale),
            optics.blur_sigma,
            optics.kernel,
            optics.prior_sigma,
        )
        self.source = _Frames(plane.frames, self.n_int, lr_shape, self.pads)
        self.span = _range(self.source.ref)
        self.tau_dn, self.sigma, self.noise = tau * self.span, plane.noise_sigma, plane.noise_sigma
        frac = [(float(a), float(b)) for a, b in sh - self.n_int]
        lam = max((self.sigma / self.tau_dn) ** 2, 1e-6)
        self.solver = FourierSolver(model, frac, lam=lam)
        self.t0_start = self.solver.t[0].copy()
        n = len(plane.frames)
        for start in range(0, n, _CHUNK):
            chunk = list(range(start, min(start + _CHUNK, n)))
            work = self.source.work(len(chunk))
            jobs = list(zip(chunk, work, strict=True))
            parallel_map(lambda job: self.source.fill(*job), jobs, threads=self.solver.threads)
            self.solver.add_frames(chunk, work, overwrite=True)

    def robust_pass(self, X: C64) -> None:
        """Refine and clip every frame against the solution ``X``; the noise re-measured."""
        opts = self.opts
        spectra = ModelSpectra(self.solver, X, derivatives=opts.refine)
        mads = _robust_pass(self.solver, spectra, self.source, self.sigma, opts)
        del spectra
        if not opts.adapt_noise:
            return
        n, s2 = len(self.source.frames), self.solver.model.scale**2
        dof = max(1.0 - s2 / n, 0.25)
        # the residual spread sets the clipping level only: with few frames per unknown it
        # under-estimates the noise, so it must not weaken the prior
        self.sigma = max(1.4826 * float(np.median(mads)) / np.sqrt(dof), 1e-6 * self.span)
        if n >= 2 * s2:  # enough frames per unknown for the estimate to hold
            self.noise = self.sigma
            self.solver.lam = max((self.noise / self.tau_dn) ** 2, 1e-6)

    def result(self, X: C64, geometry: Geometry) -> tuple[F32, dict[str, Any]]:
        return _on_reference_grid(
            self.solver,
            X,
            self.t0_start,
            self.n_int,
            geometry,
            self.shape,
            self.pads[0],
            self.noise,
        )


def _solved(
    planes: Sequence[Plane], geometry: Geometry, tau: float, options: SolveOptions, *, final: bool
) -> tuple[list[_PlaneSolve], C64 | None]:
    """The planes' first solve and robust passes, and (``final``) the solve after the last pass.

    Without ``final`` the shifts and noise the passes measured are in the states, and no
    solution is returned (the one after the last pass is not needed for them).
    """
    states = [_PlaneSolve(p, geometry, tau, options) for p in planes]
    X = solve_joint([st.solver for st in states])
    for n in range(options.passes):
        for st, x in zip(states, X, strict=True):
            st.robust_pass(x)  # X holds the pass's model spectra now
        if n + 1 == options.passes and not final:
            return states, None
        X = solve_joint([st.solver for st in states], out=X)
    return states, X


def solve_planes(
    planes: Sequence[Plane], geometry: Geometry, *, tau: float, options: SolveOptions
) -> list[tuple[F32, dict[str, Any]]]:
    """Fuse each plane's registered frames (one solve + robust passes), solved together.

    The planes share the frame size and ``geometry``; each has its own frames, shifts,
    optics and noise. Shifts are refined (``options.refine``) in planes of at least
    ``scale**2`` frames. Every solve of every plane is one batched block solve
    (:func:`~elphel_host.mfsr.forward.solve_joint`); the robust passes run plane by plane.

    Parameters
    ----------
    planes
        The sets of frames, all of one size.
    geometry
        Scale, pixel aperture and the output grid's offset.
    tau
        The prior's expected HR gradient (fraction of each plane's reference range).
    options
        Passes, clipping, padding, refinement, whether the passes may re-measure the noise.

    Returns
    -------
    list of (image, info)
        Per plane: the HR image (float32) and ``noise_sigma`` (the one that set the prior's
        weight), ``lambda`` and ``shifts_refined``.
    """
    states, X = _solved(planes, geometry, tau, options, final=True)
    assert X is not None  # final: solved after the last pass
    return [st.result(x, geometry) for st, x in zip(states, X, strict=True)]


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

    :func:`solve_planes` with one plane; arguments as there, and ``frames`` and
    ``shifts`` as for :func:`elphel_host.mfsr.robust.reconstruct` (checked there).
    """
    plane = Plane(frames, shifts, optics, noise_sigma)
    return solve_planes([plane], geometry, tau=tau, options=options)[0]


def measure_passes(
    frames: Sequence[F32],
    shifts: Shifts,
    geometry: Geometry,
    optics: Optics,
    *,
    tau: float,
    noise_sigma: float,
    options: SolveOptions,
) -> dict[str, Any]:
    """What :func:`solve`'s robust passes measure, without the image: its ``info``.

    The same ``noise_sigma``, ``lambda`` and ``shifts_refined`` as :func:`solve` gives with
    these arguments; the solve after the last pass and the HR image are left out.
    """
    plane = Plane(frames, shifts, optics, noise_sigma)
    [st], _ = _solved([plane], geometry, tau, options, final=False)
    return _details(st.solver, st.t0_start, st.n_int, geometry, st.noise)


def _details(
    solver: FourierSolver,
    t0_start: NDArray[np.float64],
    n_int: NDArray[np.int_],
    geometry: Geometry,
    noise: float,
) -> dict[str, Any]:
    """The solve's noise, prior weight and shifts (LR px, on the reference's grid).

    The shifts are refined jointly, the reference's too: the common part of the
    refinements is a drift of the model's grid away from the reference frame (a global
    shift is invisible to the data), taken out here.
    """
    drift = solver.t[0] - t0_start
    refined = (
        solver.shifts_lr() - drift / geometry.scale + n_int - np.asarray(geometry.origin_shift)
    )
    return {
        "noise_sigma": noise,
        "lambda": solver.lam,
        "shifts_refined": [[float(a), float(b)] for a, b in refined],
    }


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

    The model's grid drifts with the joint refinement (:func:`_details`): the image is
    resampled by that drift.
    """
    scale = int(geometry.scale)
    h, w = shape
    drift = solver.t[0] - t0_start
    # the right-hand side is spent after the last solve: its memory takes the image
    spent = solver.rhs.view(np.float32)
    img = solver.to_image(X, shift_hr=(float(drift[0]), float(drift[1])), out=spent)
    y0 = x0 = p * scale
    out = np.ascontiguousarray(img[y0 : y0 + h * scale, x0 : x0 + w * scale])
    return out, _details(solver, t0_start, n_int, geometry, noise)


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
    same pixel aperture in LR units), a central window of up to 256 px and
    :func:`measure_passes` with one pass, shifts refined, a 256 times weaker prior;
    residuals are measured by their median.

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
    info = measure_passes(
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
