"""Fused element-wise kernels of the Fourier solver, compiled by numba (host only).

NumPy makes one pass over memory, and one temporary, per element-wise operation; the
solver's spectra are large (a full-size frame's is 10 MB) and each is touched by several
such operations in a row. Each kernel here is one pass over a band of rows:

* :func:`accumulate`: a frame's spectrum times its frequency ramp and coupling, added to
  every alias of the right-hand side;
* :func:`predict`: one frame's model spectrum, the aliases combined by the frame's
  coupling and multiplied by its (conjugate) ramp;
* :func:`place`: an alias block scattered into the HR half-spectrum;
* :func:`pseudo_data`: a frame's residual and its Huber pseudo-data.

Each pixel's arithmetic does not depend on how the rows are split: the result is the
same on any number of threads. The kernels release the GIL and are compiled on first
use (explicit signatures, cached on disk by numba).
"""

from __future__ import annotations

import numba as nb
import numpy as np
from numpy.typing import NDArray

B2 = NDArray[np.bool_]
C64 = NDArray[np.complex64]
F32 = NDArray[np.float32]
I64 = NDArray[np.int64]

_C64_IN = nb.types.Array(nb.complex64, 1, "A", readonly=True)

_ACCUMULATE_SIGNATURE = nb.void(
    nb.types.Array(nb.complex64, 3, "A"),  # rhs (A, rows, nxh), updated
    nb.types.Array(nb.complex64, 2, "A", readonly=True),  # spectrum (rows, nxh)
    _C64_IN,  # coef (A,)
    _C64_IN,  # row ramp (rows,)
    _C64_IN,  # column ramp (nxh,)
)


@nb.njit(_ACCUMULATE_SIGNATURE, cache=True, nogil=True, fastmath=True, boundscheck=False)
def accumulate(rhs: C64, spectrum: C64, coef: C64, ry: C64, rx: C64) -> None:
    """``rhs[a, y, x] += coef[a] ry[y] rx[x] spectrum[y, x]`` for every alias a."""
    n_alias, rows, cols = rhs.shape
    term = np.empty(cols, np.complex64)
    for y in range(rows):
        r = ry[y]
        for x in range(cols):
            term[x] = spectrum[y, x] * r * rx[x]
        for a in range(n_alias):
            c = coef[a]
            out = rhs[a, y]
            for x in range(cols):
                out[x] += c * term[x]


_PREDICT_SIGNATURE = nb.void(
    nb.complex64[:, ::1],  # out (rows, nxh)
    _C64_IN,  # coef (A,)
    nb.types.Array(nb.complex64, 3, "A", readonly=True),  # Z (A, rows, nxh)
    _C64_IN,  # row ramp (rows,)
    _C64_IN,  # column ramp (nxh,)
)


@nb.njit(_PREDICT_SIGNATURE, cache=True, nogil=True, fastmath=True, boundscheck=False)
def predict(out: C64, coef: C64, Z: C64, ry: C64, rx: C64) -> None:
    """``out[y, x] = ry[y] rx[x] sum_a coef[a] Z[a, y, x]`` (aliases summed in order)."""
    n_alias, rows, cols = Z.shape
    for y in range(rows):
        o = out[y]
        for x in range(cols):
            o[x] = coef[0] * Z[0, y, x]
        for a in range(1, n_alias):
            c = coef[a]
            for x in range(cols):
                o[x] += c * Z[a, y, x]
        r = ry[y]
        for x in range(cols):
            o[x] *= r * rx[x]


_PLACE_SIGNATURE = nb.void(
    nb.complex64[:, ::1],  # spec (Ny, Nxh), written
    nb.types.Array(nb.complex64, 2, "A", readonly=True),  # block (ny, nxh)
    nb.types.Array(nb.int64, 1, "A", readonly=True),  # destination row of each block row
    nb.types.Array(nb.int64, 1, "A", readonly=True),  # destination column, -1: none
    nb.boolean,  # conjugate
)


@nb.njit(_PLACE_SIGNATURE, cache=True, nogil=True, fastmath=True, boundscheck=False)
def place(spec: C64, block: C64, iy: I64, ix: I64, conjugate: bool) -> None:
    """``spec[iy[i], ix[j]] = block[i, j]`` (conjugated if asked) where ``ix[j] >= 0``."""
    for i in range(block.shape[0]):
        dst = spec[iy[i]]
        src = block[i]
        for j in range(block.shape[1]):
            c = ix[j]
            if c >= 0:
                dst[c] = np.conj(src[j]) if conjugate else src[j]


_F32_2D_IN = nb.types.Array(nb.float32, 2, "A", readonly=True)
_PSEUDO_SIGNATURE = nb.void(
    _F32_2D_IN,  # frame (rows, cols)
    nb.types.Array(nb.float32, 2, "A"),  # prediction in, pseudo-data out
    nb.types.Array(nb.boolean, 2, "A", readonly=True),  # valid pixels
    nb.float32,  # clipping level
    nb.types.Array(nb.float32, 2, "A"),  # residual out
)


@nb.njit(_PSEUDO_SIGNATURE, cache=True, nogil=True, fastmath=True, boundscheck=False)
def pseudo_data(frame: F32, pred: F32, valid: B2, clip: np.float32, resid: F32) -> None:
    """Huber pseudo-data in place of the prediction, and the residual ``frame - pred``.

    Valid pixels get ``pred + clip(frame - pred, -clip, clip)``; the others keep ``pred``.
    """
    for y in range(frame.shape[0]):
        for x in range(frame.shape[1]):
            r = frame[y, x] - pred[y, x]
            resid[y, x] = r
            if valid[y, x]:
                pred[y, x] += min(max(r, -clip), clip)
