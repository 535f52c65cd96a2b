"""The reference lattice transform: one colour lattice of one camera, for a batch of tiles.

This is the shifted CLT in complex form (see :mod:`elphel_host.tp.clt.transform`) of one
sampling lattice, written as directly from the definition as batching allows: the
windowed samples go through the two separable stages of the transform and each tile is
rotated by its own shift. It is the reference of the production path
(:mod:`elphel_host.tp.clt.batch`), which computes the same numbers in fewer, larger
matrix products; the tests check the two against each other and this one against
:func:`~elphel_host.tp.clt.transform.clt_tiles` of the colour plane.

A colour lattice (8x8 samples of a Bayer colour, or 16x16 of a mono sensor) is
transformed as if its samples sat on the even tile positions; the true offset j0 (0 or
1) is added to the fractional shift, since moving the samples by one pixel is exactly a
phase rotation by s = 1 (``E[k, n+1] = E[k, n] exp(i pi (2k+1)/16)``). The fractional part
of each camera's tile position is the shifted window plus the same rotation (reference
2.5), so the images are never resampled.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from elphel_host.tp.bayer import Lattice
from elphel_host.tp.clt.transform import E_COMPLEX, OMEGA, TILE, N
from elphel_host.tp.geometry import TilePlacement

F32 = NDArray[np.float32]
C64 = NDArray[np.complex64]


@lru_cache(maxsize=8)
def _stage_matrices(step: int) -> tuple[F32, F32]:
    """Real matrices of the two separable stages of a lattice transform.

    Stage 1 (rows, x): samples (n) -> interleaved complex over kh (16 reals).
    Stage 2 (columns, y): interleaved complex over t (2n reals) -> [z2 over kv, z1 over kv]
    interleaved (32 reals).
    """
    e = E_COMPLEX[:, ::step]  # (8 k, n), lattice samples on the even positions
    n = e.shape[1]
    a1 = np.empty((n, 2 * N))
    a1[:, 0::2] = e.real.T
    a1[:, 1::2] = e.imag.T
    a2 = np.zeros((2 * n, 4 * N))
    for which, ev in enumerate((e, np.conj(e))):
        cols = slice(2 * N * which, 2 * N * (which + 1))
        blk = np.zeros((2 * n, 2 * N))
        blk[0::2, 0::2] = ev.real.T  # Yr -> re
        blk[0::2, 1::2] = ev.imag.T  # Yr -> im
        blk[1::2, 0::2] = -ev.imag.T  # Yi -> re
        blk[1::2, 1::2] = ev.real.T  # Yi -> im
        a2[:, cols] = blk
    return a1.astype(np.float32), a2.astype(np.float32)


def lattice_spectra(sub: F32, lattice: Lattice, at: TilePlacement, *, pad: int) -> C64:
    """Shifted CLT (complex form) of one lattice of one camera for a batch of tiles.

    Parameters
    ----------
    sub
        The lattice's padded sub-image (:func:`elphel_host.tp.bayer.sublattice`).
    lattice
        Which lattice.
    at
        Where the camera's tiles lie on the sensor.
    pad
        Padding of ``sub`` in sub-image samples.

    Returns
    -------
    numpy.ndarray
        ``(T, 8, 2, 8)`` complex64: [kh, (z2, z1), kv].
    """
    left_x, shift_x, top_y, shift_y = at.left_x, at.shift_x, at.top_y, at.shift_y
    st = lattice.step
    n = lattice.samples
    t = left_x.shape[0]
    # first lattice sample inside each window, and its offset j0 from the window start
    mx = -((lattice.col - left_x) // st)
    my = -((lattice.row - top_y) // st)
    j0x = st * mx + lattice.col - left_x
    j0y = st * my + lattice.row - top_y
    h, w = sub.shape
    gx = np.clip(mx + pad, 0, w - n)
    gy = np.clip(my + pad, 0, h - n)
    view = np.lib.stride_tricks.sliding_window_view(sub, (n, n))
    block = view[gy, gx]  # (T, n, n) copy
    pos = np.arange(n) * st + 0.5
    wx = np.sin(np.pi / TILE * (pos[None, :] + (j0x + shift_x)[:, None])).astype(np.float32)
    wy = np.sin(np.pi / TILE * (pos[None, :] + (j0y + shift_y)[:, None])).astype(np.float32)
    block *= wy[:, :, None]
    block *= wx[:, None, :]
    a1, a2 = _stage_matrices(st)
    y = (block.reshape(t * n, n) @ a1).view(np.complex64).reshape(t, n, N)
    rot_h = np.exp(1j * ((j0x + shift_x)[:, None] * OMEGA[None, :])).astype(np.complex64)
    y *= rot_h[:, None, :]
    yt = np.ascontiguousarray(y.transpose(0, 2, 1)).view(np.float32).reshape(t * N, 2 * n)
    z = (yt @ a2).view(np.complex64).reshape(t, N, 2, N)
    rot_v = np.exp(1j * ((j0y + shift_y)[:, None] * OMEGA[None, :])).astype(np.complex64)
    z[:, :, 0, :] *= rot_v[:, None, :]
    z[:, :, 1, :] *= np.conj(rot_v)[:, None, :]
    return z
