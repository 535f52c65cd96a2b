"""Fused element-wise kernels of the Fourier solver, compiled by numba (host only).

NumPy makes one pass over memory, and one temporary, per element-wise operation; the
solver's spectra are large (a full-size frame's is 10 MB) and each is touched by several
such operations in a row. Each kernel here is one pass over a band of rows:

* :func:`accumulate`: frames' spectra times their frequency ramps and couplings, added
  to every alias of the right-hand side;
* :func:`predict`: one frame's model spectrum, the aliases combined by the frame's
  coupling and multiplied by its (conjugate) ramp;
* :func:`place`: an alias block scattered into the HR half-spectrum;
* :func:`pseudo_data`: a frame's Huber pseudo-data and a sample of its residual.

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

# Complex arrays go in as float32 views (re, im interleaved): the compiler vectorises
# the real arithmetic written out, not numba's complex type.
_F32_ROWS = nb.types.Array(nb.float32, 2, "A", readonly=True)
_F32_3D_IN = nb.types.Array(nb.float32, 3, "A", readonly=True)
# one signature per number of frames a call takes (a chunk of at most MAX_FRAMES)
MAX_FRAMES = 4
_ACCUMULATE_SIGNATURES = [
    nb.void(
        nb.types.Array(nb.float32, 3, "A"),  # rhs (A, rows, 2 nxh), updated
        nb.types.UniTuple(_F32_ROWS, n),  # the frames' spectra (rows, 2 nxh)
        _F32_ROWS,  # coef (K, 2 A)
        _F32_ROWS,  # row ramps (K, 2 rows)
        _F32_ROWS,  # column ramps (K, 2 nxh)
    )
    for n in range(1, MAX_FRAMES + 1)
]


@nb.njit(_ACCUMULATE_SIGNATURES, cache=True, nogil=True, fastmath=True, boundscheck=False)
def _accumulate(rhs: F32, spectra: tuple[F32, ...], coef: F32, ry: F32, rx: F32) -> None:
    n_alias, rows, cols = rhs.shape[0], rhs.shape[1], rhs.shape[2] // 2
    tr = np.empty(cols, np.float32)
    ti = np.empty(cols, np.float32)
    for y in range(rows):
        for k in range(len(spectra)):
            rr, ri = ry[k, 2 * y], ry[k, 2 * y + 1]
            sp = spectra[k][y]
            for x in range(cols):
                ar = sp[2 * x] * rr - sp[2 * x + 1] * ri
                ai = sp[2 * x] * ri + sp[2 * x + 1] * rr
                xr, xi = rx[k, 2 * x], rx[k, 2 * x + 1]
                tr[x] = ar * xr - ai * xi
                ti[x] = ar * xi + ai * xr
            for a in range(n_alias):
                cr, ci = coef[k, 2 * a], coef[k, 2 * a + 1]
                out = rhs[a, y]
                for x in range(cols):
                    out[2 * x] += cr * tr[x] - ci * ti[x]
                    out[2 * x + 1] += cr * ti[x] + ci * tr[x]


def accumulate(rhs: C64, spectra: tuple[C64, ...], coef: C64, ry: C64, rx: C64) -> None:
    """``rhs[a, y, x] += sum_k coef[k, a] ry[k, y] rx[k, x] spectra[k][y, x]``, k in order.

    ``rhs`` (A, rows, nxh) is updated row by row, so that the rows of every alias stay in
    the cache while the (at most :data:`MAX_FRAMES`) frames are added.
    """
    _accumulate(
        rhs.view(np.float32),
        tuple(spec.view(np.float32) for spec in spectra),
        _floats(coef),
        _floats(ry),
        _floats(rx),
    )


def _floats(a: C64) -> F32:
    """A complex64 array as float32 (re, im interleaved along its last axis)."""
    return np.ascontiguousarray(a, np.complex64).view(np.float32)


_PREDICT_SIGNATURE = nb.void(
    nb.types.Array(nb.float32, 2, "A"),  # out (rows, 2 nxh)
    nb.types.Array(nb.float32, 1, "A", readonly=True),  # coef (2 A,)
    _F32_3D_IN,  # Z (A, rows, 2 nxh)
    nb.types.Array(nb.float32, 1, "A", readonly=True),  # row ramp (2 rows,)
    nb.types.Array(nb.float32, 1, "A", readonly=True),  # column ramp (2 nxh,)
)


@nb.njit(_PREDICT_SIGNATURE, cache=True, nogil=True, fastmath=True, boundscheck=False)
def _predict(out: F32, coef: F32, Z: F32, ry: F32, rx: F32) -> None:
    n_alias, rows, cols = Z.shape[0], Z.shape[1], Z.shape[2] // 2
    for y in range(rows):
        o = out[y]
        for x in range(2 * cols):
            o[x] = 0.0
        for a in range(n_alias):
            cr, ci = coef[2 * a], coef[2 * a + 1]
            z = Z[a, y]
            for x in range(cols):
                o[2 * x] += cr * z[2 * x] - ci * z[2 * x + 1]
                o[2 * x + 1] += cr * z[2 * x + 1] + ci * z[2 * x]
        rr, ri = ry[2 * y], ry[2 * y + 1]
        for x in range(cols):
            pr = rr * rx[2 * x] - ri * rx[2 * x + 1]
            pi = rr * rx[2 * x + 1] + ri * rx[2 * x]
            qr, qi = o[2 * x], o[2 * x + 1]
            o[2 * x] = qr * pr - qi * pi
            o[2 * x + 1] = qr * pi + qi * pr


def predict(out: C64, coef: C64, Z: C64, ry: C64, rx: C64) -> None:
    """``out[y, x] = ry[y] rx[x] sum_a coef[a] Z[a, y, x]`` (aliases summed in order)."""
    _predict(out.view(np.float32), _floats(coef), Z.view(np.float32), _floats(ry), _floats(rx))


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
_PSEUDO_SIGNATURE = nb.int64(
    _F32_2D_IN,  # frame (rows, cols)
    nb.types.Array(nb.float32, 2, "A"),  # prediction in, pseudo-data out
    nb.types.Array(nb.boolean, 2, "A", readonly=True),  # valid pixels
    nb.float32,  # clipping level
    nb.int64,  # the sample's step
    nb.types.Array(nb.float32, 1, "A"),  # the sample out
)


@nb.njit(_PSEUDO_SIGNATURE, cache=True, nogil=True, fastmath=True, boundscheck=False)
def pseudo_data(frame: F32, pred: F32, valid: B2, clip: np.float32, step: int, sample: F32) -> int:
    """Huber pseudo-data in place of the prediction, and a sample of the residual's size.

    Valid pixels get ``pred + clip(frame - pred, -clip, clip)``; the others keep ``pred``.
    ``sample`` receives ``|frame - pred|`` of the valid pixels on every ``step``-th row
    and column, in row order (it needs ``ceil(rows / step) * ceil(cols / step)``
    places); returns how many.
    """
    n = 0
    for y in range(frame.shape[0]):
        on_row = y % step == 0
        for x in range(frame.shape[1]):
            r = frame[y, x] - pred[y, x]
            if valid[y, x]:
                pred[y, x] += min(max(r, -clip), clip)
                if on_row and x % step == 0:
                    sample[n] = abs(r)
                    n += 1
    return n
