"""The robust pass's step for one frame: shift refined against the model, residual clipped.

Huber regression by pseudo-data; :mod:`elphel_host.mfsr.forward` has the model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from elphel_host.mfsr.forward import C64, F32, FourierSolver
from elphel_host.mfsr.kernels import (
    packed_irfft2,
    predict,
    pseudo_data,
    shift_normal_equations,
)
from elphel_host.parallel import parallel_map

_SPREAD_STEP = 3  # the residual's sample: every third row and column


@dataclass(frozen=True)
class PaddedFrame:
    """An LR frame as it sits on the solver's padded grid, without a padded copy.

    Padded pixel (y, x) shows ``frame[y - offset[0], x - offset[1]]`` for y in
    ``valid[0]:valid[1]`` and x in ``valid[2]:valid[3]``; the other pixels are padding,
    or not covered by this frame.
    """

    frame: F32
    offset: tuple[int, int]
    valid: tuple[int, int, int, int]


class ModelSpectra:
    """Per-pass spectra of the solution: prediction and its shift derivatives by alias.

    ``derivatives=False`` leaves the derivatives out (a pass that only clips). The
    prediction's spectra take over the solution's memory: ``X`` holds them afterwards.
    """

    def __init__(self, solver: FourierSolver, X: C64, *, derivatives: bool = True) -> None:
        ny, nx = solver.model.lr_shape
        Ny, Nx = solver.model.hr_shape
        s2 = np.float32(1.0 / solver.model.scale**2)
        d_all = solver.block_factors()[0]

        def alias(a: int) -> None:
            # (re, im) times the real transfer: no complex temporaries
            z = X[a].view(np.float32).reshape(ny, -1, 2)
            np.multiply(z, d_all[a][:, :, None], out=z)
            z *= s2

        parallel_map(alias, range(len(solver.offsets)), threads=solver.threads)
        self.Z = np.ascontiguousarray(X)  # X itself: solutions are C-ordered
        self.Zy = np.empty(X.shape, np.complex64) if derivatives else None
        self.Zx = np.empty(X.shape, np.complex64) if derivatives else None
        if self.Zy is None or self.Zx is None:
            return
        for a, (jy, jx) in enumerate(solver.offsets):
            wy = (2j * np.pi * (solver._vy + jy * ny) / Ny).astype(np.complex64)
            wx = (2j * np.pi * (solver._vx + jx * nx) / Nx).astype(np.complex64)
            np.multiply(X[a], wy[:, None], out=self.Zy[a])
            np.multiply(X[a], wx[None, :], out=self.Zx[a])


def refine_and_pseudo(
    solver: FourierSolver,
    spectra: ModelSpectra,
    k: int,
    frame: PaddedFrame,
    out: F32,
    *,
    huber: float,
    sigma: float,
    refine: bool,
) -> tuple[tuple[float, float], F32]:
    """One frame's robust step: refine its shift against the model, then clip its residual.

    The shift update is one Gauss-Newton step over the frame's valid, non-outlier pixels
    (the mirror padding moves the opposite way and must not vote). ``out`` (float32, the
    padded grid's shape) receives the pseudo-data (prediction + clipped residual on
    valid pixels, prediction elsewhere). Returns the shift update (HR px, to add to frame
    k's position) and the residual's absolute values on the valid pixels of every third
    row and column (the sample its spread is measured on).
    """
    ny, nx = solver.model.lr_shape
    ck = solver.C[k].conj()
    ry, rx = solver.ramps(k)
    ryc, rxc = ry.conj(), rx.conj()

    def model(rows: C64, image: F32) -> F32:
        """The frame's image of the alias spectra ``rows``, in ``image``."""
        # no BLAS: a threaded BLAS sums in an order that depends on its thread count, and
        # a burst must fuse to the same numbers in every process (the fusion fed while
        # capturing and `elphel mfsr` afterwards agree bit for bit)
        predict(image, ck, rows, ryc, rxc)
        return packed_irfft2(image)

    pred = model(spectra.Z, out)
    dt = (0.0, 0.0)
    if refine:
        if spectra.Zy is None or spectra.Zx is None:
            raise ValueError("refine=True with spectra made without derivatives")
        dy = model(spectra.Zy, np.empty((ny, nx), np.float32))
        dx = model(spectra.Zx, np.empty((ny, nx), np.float32))
        a11, a12, a22, b1, b2 = shift_normal_equations(
            pred, dy, dx, frame.frame, frame.offset, frame.valid, huber * sigma
        )
        det = a11 * a22 - a12 * a12
        if det > 1e-12 * max(a11 * a22, 1e-30):
            dt = ((a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det)
            pred += dt[0] * dy + dt[1] * dx
    sample = np.empty(-(-ny // _SPREAD_STEP) * -(-nx // _SPREAD_STEP), np.float32)
    clip = np.float32(huber * sigma)
    # pred becomes the pseudo-data
    n = pseudo_data(pred, frame.frame, frame.offset, frame.valid, clip, _SPREAD_STEP, sample)
    return dt, sample[:n]
