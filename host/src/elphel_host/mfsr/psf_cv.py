"""Cross-validation of a reconstruction's optics and prior on a burst's central window.

The frames of the window are aligned to the reference and mirror-padded as the
reconstruction does them, and split into interleaved groups (frames k with
``k % folds == g``). For each group the others' spectra are accumulated once (the
right-hand side of the Fourier solver does not depend on the optics or the prior); a
candidate model (blur sigma or kernel, prior shape, prior weight) is then solved exactly
from them (every group in one batched block solve) and the group's frames are predicted.
The mean squared prediction error over the pixels each held-out frame covers, away from
the padding, scores the candidate (:mod:`elphel_host.mfsr.psf`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.fft as sfft
from numpy.typing import NDArray

from elphel_host.mfsr.forward import ForwardModel, FourierSolver
from elphel_host.mfsr.frames import aligned, central_window, check_frames, estimate_noise, padded
from elphel_host.mfsr.kernels import packed_irfft2, predict, squared_residual
from elphel_host.mfsr.ldl import solve_blocks

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]


def _fit_scale(n: int, folds: int, scale: int, aperture: int) -> int:
    """The largest scale s <= scale whose training sets stay determined.

    Its pixel aperture must be whole in its HR px; the sigma found there is converted to
    the output's HR px.
    """
    train_n = n - (n + folds - 1) // folds
    fit = next(
        (s for s in range(scale, 1, -1) if train_n >= s * s and (aperture * s) % scale == 0),
        None,
    )
    if folds < 2 or fit is None:
        raise ValueError(
            f"{n} frames; allowed: at least 5 frames, so that a fit at x2 without one of "
            f"{folds} groups is determined"
        )
    return fit


def _window_frames(
    crop: Sequence[F32], n_int: NDArray[np.int_]
) -> tuple[list[F32], list[tuple[int, int, int, int]]]:
    """The window's frames aligned and padded as the solve does, and where each is scored.

    A frame is scored on the padded pixels it covers, away from the padding's seam: a
    rectangle (rows y0:y1, columns x0:x1; empty when it covers none of them).
    """
    wy, wx = crop[0].shape
    p = min(16, wy - 1, wx - 1)
    ny, nx = sfft.next_fast_len(wy + 2 * p), sfft.next_fast_len(wx + 2 * p)
    pads = (p, ny - wy - p, p, nx - wx - p)
    if pads[1] >= wy or pads[3] >= wx:
        ny, nx = wy + 2 * p, wx + 2 * p
        pads = (p, p, p, p)
    m = 4  # LR px kept clear of the padding's seam
    fr: list[F32] = []
    scored: list[tuple[int, int, int, int]] = []
    for k, frame in enumerate(crop):
        sy, sx = int(n_int[k, 0]), int(n_int[k, 1])
        f, _ = aligned(frame, crop[0], (sy, sx))
        fr.append(np.asarray(padded(f, pads, mode="reflect"), np.float32))
        y0, y1 = p + max(m, sy), p + min(wy - m, wy + sy)
        x0, x1 = p + max(m, sx), p + min(wx - m, wx + sx)
        scored.append((y0, y1, x0, x1) if y1 > y0 and x1 > x0 else (0, 0, 0, 0))
    return fr, scored


class CrossValidation:
    """A burst's central window, aligned and padded, in interleaved groups of frames.

    Per group: the other frames' right-hand side and normal matrix (stacked along a batch
    axis, group second), and the group's own frames with their couplings and frequency
    ramps for the prediction (groups of fewer frames padded with empty masks).
    """

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
        self.fit_scale = _fit_scale(n, folds, int(scale), ap)
        self.aperture = ap * self.fit_scale // int(scale)
        crop = central_window([np.asarray(f, np.float32) for f in frames], window)
        sh = np.asarray(shifts, np.float64) + np.asarray(origin_shift, np.float64)
        n_int = np.rint(sh).astype(int)
        frac = [(float(a), float(b)) for a, b in sh - n_int]
        fr, scored = _window_frames(crop, n_int)
        self.shape = fr[0].shape
        groups = [[k for k in range(n) if k % folds == g] for g in range(folds)]
        self._training(fr, frac, groups)
        self._held_out(fr, scored, frac, groups)
        lo, hi = np.percentile(crop[0], [0.1, 99.9])
        self.span = max(float(hi - lo), 1e-6)
        sigma_n = float(noise_sigma) if noise_sigma is not None else estimate_noise(crop[0])
        self.sigma_n = max(sigma_n, 1e-6 * self.span)

    def _model(
        self, sigma: float = 0.0, kernel: F64 | None = None, prior: float = 0.0
    ) -> ForwardModel:
        return ForwardModel(self.shape, self.fit_scale, self.aperture, sigma, kernel, prior)

    def _training(
        self, frames: list[F32], frac: list[tuple[float, float]], groups: list[list[int]]
    ) -> None:
        """Each group's training right-hand side and normal matrix, stacked by group."""
        rhs, gram = [], []
        for test in groups:
            train = [k for k in range(len(frames)) if k not in test]
            acc = FourierSolver(self._model(), [frac[k] for k in train], lam=1.0)
            # the solver's frames are numbered 0..len(train)-1
            acc.add_frames(list(range(len(train))), [frames[k] for k in train])
            rhs.append(acc.rhs)
            gram.append(acc.G)
        self.rhs = np.stack(rhs, axis=1)  # (A, F, ny, nxh)
        self.gram = np.stack(gram, axis=-1).astype(np.complex64)[..., None, None]

    def _held_out(
        self,
        frames: list[F32],
        scored: list[tuple[int, int, int, int]],
        frac: list[tuple[float, float]],
        groups: list[list[int]],
    ) -> None:
        """Each group's frames to predict: targets, scored rectangles, couplings, ramps.

        Indexed (group, frame of the group); groups of fewer frames are padded with empty
        rectangles.
        """
        t = max(len(g) for g in groups)
        ny, nx = self.shape
        self.targets = np.zeros((len(groups), t, ny, nx), np.float32)
        self.scored = np.zeros((len(groups), t, 4), np.int64)
        model = self._model()
        self.coupling = np.zeros((len(groups), t, len(model.alias_offsets())), np.complex64)
        self.ry = np.ones((len(groups), t, ny), np.complex64)
        self.rx = np.ones((len(groups), t, nx // 2 + 1), np.complex64)
        for f, test in enumerate(groups):
            pred = FourierSolver(model, [frac[k] for k in test], lam=1.0)
            for i, k in enumerate(test):
                self.targets[f, i] = frames[k]
                self.scored[f, i] = scored[k]
                self.coupling[f, i] = pred.C[i].conj()
                ry, rx = pred.ramps(i)
                self.ry[f, i], self.rx[f, i] = ry.conj(), rx.conj()
        rows = self.scored[..., 1] - self.scored[..., 0]
        self.counts = np.maximum((rows * (self.scored[..., 3] - self.scored[..., 2])).sum(1), 1)

    def errors(
        self,
        sigma: float,
        tau: float,
        kernel: NDArray[np.float64] | None = None,
        prior_sigma: float = 0.0,
    ) -> F64:
        """Each group's prediction error for the model (sigma, tau, kernel, prior_sigma)."""
        lam = max((self.sigma_n / (tau * self.span)) ** 2, 1e-6)
        model = self._model(sigma, kernel, prior_sigma)
        d, l2 = FourierSolver(model, [(0.0, 0.0)], lam=lam).block_factors()
        s2 = np.float32(self.fit_scale**2)
        groups, n_alias = self.rhs.shape[1], self.rhs.shape[0]
        X = np.empty((groups, n_alias, *self.rhs.shape[2:]), np.complex64)  # C-ordered
        solve_blocks(
            d[:, None],
            self.gram,
            l2[:, None],
            self.rhs,
            weight=float(lam * s2),
            scale=float(s2),
            out=np.moveaxis(X, 0, 1),
        )
        X *= d / s2  # the model's LR spectra by alias
        image = np.empty(self.shape, np.float32)
        sq = np.zeros(groups, np.float64)
        for f in range(groups):
            for i in range(self.targets.shape[1]):
                if self.scored[f, i, 1] <= self.scored[f, i, 0]:
                    continue
                predict(image, self.coupling[f, i], X[f], self.ry[f, i], self.rx[f, i])
                pred = packed_irfft2(image)
                sq[f] += squared_residual(self.targets[f, i], pred, tuple(self.scored[f, i]))
        return np.asarray(sq / self.counts, np.float64)
