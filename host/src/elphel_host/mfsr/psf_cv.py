"""Cross-validation of a reconstruction's optics and prior on a burst's central window.

The frames of the window are aligned to the reference and mirror-padded as the
reconstruction does them, and split into interleaved groups (frames k with
``k % folds == g``). For each group the others' spectra are accumulated once (the
right-hand side of the Fourier solver does not depend on the optics or the prior); a
candidate model (blur sigma or kernel, prior shape, prior weight) is then solved exactly
from them and the group's frames are predicted. The mean squared prediction error over
the groups' interior valid pixels scores the candidate (:mod:`elphel_host.mfsr.psf`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.fft as sfft
from numpy.typing import NDArray

from elphel_host.mfsr.forward import ForwardModel, FourierSolver
from elphel_host.mfsr.frames import aligned, central_window, check_frames, estimate_noise, padded
from elphel_host.mfsr.ldl import solve_blocks
from elphel_host.parallel import parallel_map

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]


class Fold:
    """One cross-validation group: the others' right-hand side, its own frames to predict."""

    def __init__(
        self,
        shape: tuple[int, int],
        scale: int,
        aperture: int,
        frac: F64,
        frames: Sequence[F32],
        valid: Sequence[NDArray[np.bool_]],
        test: list[int],
        interior: NDArray[np.bool_],
    ) -> None:
        train = [k for k in range(len(frames)) if k not in test]
        self.shape, self.scale, self.aperture = shape, scale, aperture
        self.train_shifts = [(float(frac[k, 0]), float(frac[k, 1])) for k in train]
        acc = FourierSolver(ForwardModel(shape, scale, aperture), self.train_shifts, lam=1.0)
        # the solver's frames are numbered 0..len(train)-1
        acc.add_frames(list(range(len(train))), [frames[k] for k in train])
        self.rhs = acc.rhs
        self.test = test
        pred = FourierSolver(
            ForwardModel(shape, scale, aperture),
            [(float(frac[k, 0]), float(frac[k, 1])) for k in test],
            lam=1.0,
        )
        self.pred_solver = pred
        self.targets = np.stack([frames[k] for k in test])
        self.masks = np.stack([valid[k] & interior for k in test])

    def error(
        self,
        sigma: float,
        lam: float,
        kernel: NDArray[np.float64] | None = None,
        prior_sigma: float = 0.0,
    ) -> float:
        """Mean squared prediction error of the held-out frames for (sigma, lam)."""
        model = ForwardModel(self.shape, self.scale, self.aperture, sigma, kernel, prior_sigma)
        solver = FourierSolver(model, self.train_shifts, lam=lam)
        s2 = np.float32(self.scale**2)
        d, l2 = solver._block_factors()
        mu = np.float32(lam) * s2 * l2
        X = solve_blocks(d, solver.G.astype(np.complex64), mu, s2 * d * self.rhs)
        ps = self.pred_solver
        ny, nx = self.shape
        z = ((d / s2) * X).reshape(len(solver.offsets), -1)
        q = (ps.C.conj() @ z).reshape(len(self.test), ny, ps.nxh)
        for i in range(len(self.test)):
            ry, rx = ps._ramps(i)
            q[i] *= ry.conj()[:, None]
            q[i] *= rx.conj()[None, :]
        pred = sfft.irfft2(q, s=(ny, nx), axes=(-2, -1), workers=1)
        r = (self.targets - pred)[self.masks]
        return float(np.dot(r, r)) / max(int(r.size), 1)


class CrossValidation:
    """A burst's central window, aligned and padded, in interleaved groups of frames."""

    def __init__(
        self,
        frames: Sequence[F32],
        shifts: Sequence[tuple[float, float]],
        scale: int,
        aperture: int | None,
        origin_shift: tuple[float, float],
        noise_sigma: float | None,
        window: int,
        folds: int,
    ) -> None:
        n = len(frames)
        check_frames(frames)
        if len(shifts) != n:
            raise ValueError(f"len(shifts)={len(shifts)}; allowed: {n} (one per frame)")
        ap = int(aperture or scale)
        folds = min(folds, n)
        train_n = n - (n + folds - 1) // folds
        # the largest scale s <= scale whose training sets stay determined (and whose pixel
        # aperture is whole in its HR px); its sigma is converted to the output's HR px
        fit_scale = next(
            (s for s in range(int(scale), 1, -1) if train_n >= s * s and (ap * s) % scale == 0),
            None,
        )
        if folds < 2 or fit_scale is None:
            raise ValueError(
                f"{n} frames; allowed: at least 5 frames, so that a fit at x2 without one of "
                f"{folds} groups is determined"
            )
        ap_fit = ap * fit_scale // int(scale)
        crop = central_window([np.asarray(f, np.float32) for f in frames], window)
        wy, wx = crop[0].shape
        ref = crop[0]
        sh = np.asarray(shifts, np.float64) + np.asarray(origin_shift, np.float64)
        n_int = np.rint(sh).astype(int)
        frac = sh - n_int
        p = min(16, wy - 1, wx - 1)
        ny, nx = sfft.next_fast_len(wy + 2 * p), sfft.next_fast_len(wx + 2 * p)
        pads = (p, ny - wy - p, p, nx - wx - p)
        if pads[1] >= wy or pads[3] >= wx:
            ny, nx = wy + 2 * p, wx + 2 * p
            pads = (p, p, p, p)
        fr: list[F32] = []
        va: list[NDArray[np.bool_]] = []
        for k in range(n):
            f, v = aligned(crop[k], ref, (int(n_int[k, 0]), int(n_int[k, 1])))
            fr.append(np.asarray(padded(f, pads, mode="reflect"), np.float32))
            va.append(np.asarray(padded(v, pads, mode="zero"), bool))
        interior = np.zeros((ny, nx), bool)
        m = 4  # LR px kept clear of the padding's seam
        interior[p + m : p + wy - m, p + m : p + wx - m] = True
        groups = [[k for k in range(n) if k % folds == g] for g in range(folds)]
        self.fit_scale = fit_scale
        self.folds = [Fold((ny, nx), fit_scale, ap_fit, frac, fr, va, g, interior) for g in groups]

        lo, hi = np.percentile(ref, [0.1, 99.9])
        self.span = max(float(hi - lo), 1e-6)
        sigma_n = float(noise_sigma) if noise_sigma is not None else estimate_noise(ref)
        self.sigma_n = max(sigma_n, 1e-6 * self.span)

    def errors(
        self,
        sigma: float,
        tau: float,
        kernel: NDArray[np.float64] | None = None,
        prior_sigma: float = 0.0,
    ) -> F64:
        """Each group's prediction error for the model (sigma, tau, kernel, prior_sigma)."""
        lam = max((self.sigma_n / (tau * self.span)) ** 2, 1e-6)
        return np.array(
            parallel_map(lambda f: f.error(sigma, lam, kernel, prior_sigma), self.folds)
        )
