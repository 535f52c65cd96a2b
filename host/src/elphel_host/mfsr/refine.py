"""The robust pass's step for one frame: shift refined against the model, residual clipped.

Huber regression by pseudo-data; :mod:`elphel_host.mfsr.forward` has the model.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from elphel_host.mfsr.forward import C64, F32, FourierSolver
from elphel_host.mfsr.kernels import packed_irfft2, predict, pseudo_data

_SPREAD_STEP = 3  # the residual's sample: every third row and column


class ModelSpectra:
    """Per-pass spectra of the solution: prediction and its shift derivatives by alias.

    ``derivatives=False`` leaves the derivatives out (a pass that only clips).
    """

    def __init__(self, solver: FourierSolver, X: C64, *, derivatives: bool = True) -> None:
        ny, nx = solver.model.lr_shape
        Ny, Nx = solver.model.hr_shape
        s2 = float(solver.model.scale**2)
        A = len(solver.offsets)
        nxh = solver.nxh
        self.Z = np.empty((A, ny, nxh), np.complex64)
        self.Zy = np.empty_like(self.Z) if derivatives else None
        self.Zx = np.empty_like(self.Z) if derivatives else None
        d_all = solver.block_factors()[0]
        for a, (jy, jx) in enumerate(solver.offsets):
            z = self.Z[a]
            np.multiply(X[a], d_all[a], out=z)
            z *= np.float32(1.0 / s2)
            if self.Zy is None or self.Zx is None:
                continue
            wy = (2j * np.pi * (solver._vy + jy * ny) / Ny).astype(np.complex64)
            wx = (2j * np.pi * (solver._vx + jx * nx) / Nx).astype(np.complex64)
            np.multiply(z, wy[:, None], out=self.Zy[a])
            np.multiply(z, wx[None, :], out=self.Zx[a])


def _dot(a: F32, b: F32) -> float:
    return float(np.einsum("i,i->", a, b, dtype=np.float64))


def refine_and_pseudo(
    solver: FourierSolver,
    spectra: ModelSpectra,
    k: int,
    frame: F32,
    valid: NDArray[np.bool_],
    *,
    huber: float,
    sigma: float,
    refine: bool,
) -> tuple[F32, tuple[float, float], F32]:
    """One frame's robust step: refine its shift against the model, then clip its residual.

    The shift update is one Gauss-Newton step over the frame's valid, non-outlier pixels
    (the mirror padding moves the opposite way and must not vote). Returns the
    pseudo-data (prediction + clipped residual on valid pixels, prediction elsewhere), the
    shift update (HR px, to add to frame k's position) and the residual's absolute values
    on the valid pixels of every third row and column (the sample its spread is measured
    on).
    """
    ny, nx = solver.model.lr_shape
    ck = solver.C[k].conj()
    ry, rx = solver.ramps(k)
    ryc, rxc = ry.conj(), rx.conj()

    def model(rows: C64) -> F32:
        """The frame's image of the alias spectra ``rows``."""
        # no BLAS: a threaded BLAS sums in an order that depends on its thread count, and
        # a burst must fuse to the same numbers in every process (the fusion fed while
        # capturing and `elphel mfsr` afterwards agree bit for bit)
        out = np.empty((ny, nx), np.float32)
        predict(out, ck, rows, ryc, rxc)
        return packed_irfft2(out)

    pred = model(spectra.Z)
    dt = (0.0, 0.0)
    if refine:
        if spectra.Zy is None or spectra.Zx is None:
            raise ValueError("refine=True with spectra made without derivatives")
        dy, dx = model(spectra.Zy).ravel(), model(spectra.Zx).ravel()
        r = (frame - pred).ravel()
        w = (valid.ravel() & (np.abs(r) <= huber * sigma)).astype(np.float32)
        dyw, dxw = dy * w, dx * w
        a11, a12, a22 = _dot(dyw, dy), _dot(dyw, dx), _dot(dxw, dx)
        b1, b2 = _dot(dyw, r), _dot(dxw, r)
        det = a11 * a22 - a12 * a12
        if det > 1e-12 * max(a11 * a22, 1e-30):
            dt = ((a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det)
            pred += (dt[0] * dy + dt[1] * dx).reshape(ny, nx)
    sample = np.empty(-(-ny // _SPREAD_STEP) * -(-nx // _SPREAD_STEP), np.float32)
    clip = np.float32(huber * sigma)
    n = pseudo_data(frame, pred, valid, clip, _SPREAD_STEP, sample)  # pred: pseudo-data now
    return pred, dt, sample[:n]
