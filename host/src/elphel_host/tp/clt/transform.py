"""The CLT itself, tile by tile: window, fold, DCT-IV/DST-IV, inverse, phase rotation.

This is the definition every faster form is checked against.

The transform follows reference/tile-processor.md section 2. A tile of 16x16 samples at
stride 8 is multiplied by the sine window, folded to 8x8 with the MDCT (cosine) or MDST
(sine) fold along each axis and transformed with DCT-IV / DST-IV. The four quadrants are
indexed q = 0..3 = CC, SC, CS, SS: bit 0 set means the sine branch horizontally, bit 1 the
sine branch vertically. Each quadrant is stored [kv][kh] (row = vertical frequency).

The same transform in complex form drives the fast correlation path: along one axis the
pair (cosine, sine) of coefficients is one complex number ``C + iS = E x`` with
``E[k, n] = 0.5 exp(i pi (2k+1)(n + n0)/16)``. In 2-D the four real quadrants are two
complex 8x8 arrays (the idempotent split of the bicomplex numbers with h^2 = v^2 = -1)::

    z2 = (CC - SS) + i (SC + CS) = E_v X E_h^T
    z1 = (CC + SS) + i (SC - CS) = conj(E_v) X E_h^T

so the quadrant products of the reference (kernel convolution, correlation, phase
rotation) are element-wise complex products on z1 and z2. A shift by s pixels rotates
z2 by exp(i(th_h + th_v)) and z1 by exp(i(th_h - th_v)), th(k) = pi s (2k+1)/16.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from elphel_host.errors import InputFormatError

N = 8  # DTT size; tiles are 2N x 2N at stride N
TILE = 2 * N
#: Angular frequency of index k, rad/pixel: a shift by s rotates coefficient k by s * OMEGA[k].
OMEGA: NDArray[np.float64] = np.pi * (2 * np.arange(N) + 1) / TILE

FloatArray = NDArray[np.floating]
ComplexArray = NDArray[np.complexfloating]

_k = np.arange(N)[:, None]
_n = np.arange(N)[None, :]
#: Orthonormal DCT-IV and DST-IV matrices (symmetric, self-inverse).
C4: NDArray[np.float64] = np.sqrt(2.0 / N) * np.cos(np.pi / (4 * N) * (2 * _k + 1) * (2 * _n + 1))
S4: NDArray[np.float64] = np.sqrt(2.0 / N) * np.sin(np.pi / (4 * N) * (2 * _k + 1) * (2 * _n + 1))


def _fold_matrices() -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Fold 16 windowed samples to 8: cosine (MDCT) and sine (MDST) branches."""
    fc = np.zeros((N, TILE))
    fs = np.zeros((N, TILE))
    for j in range(4):
        # quarters a = v[0:4], b = v[4:8], c = v[8:12], d = v[12:16]
        fc[j, 8 + 3 - j] -= 1.0
        fc[j, 12 + j] -= 1.0
        fc[4 + j, j] += 1.0
        fc[4 + j, 4 + 3 - j] -= 1.0
        fs[j, 8 + 3 - j] += 1.0
        fs[j, 12 + j] -= 1.0
        fs[4 + j, j] += 1.0
        fs[4 + j, 4 + 3 - j] += 1.0
    return fc, fs


FOLD_C, FOLD_S = _fold_matrices()
#: Fold followed by the 8-point transform, per branch: 8 x 16.
T_COS: NDArray[np.float64] = C4 @ FOLD_C
T_SIN: NDArray[np.float64] = S4 @ FOLD_S
#: Complex 1-D lapped transform: (C + iS) = E @ x, 8 x 16.
E_COMPLEX: NDArray[np.complex128] = T_COS + 1j * T_SIN


def window(shift: float | FloatArray = 0.0) -> NDArray[np.float64]:
    """Sine window of 16 samples, optionally shifted by a fraction of a pixel.

    Parameters
    ----------
    shift
        Shift s (scalar or array of any shape); ``w_s[i] = sin(pi (i + 0.5 + s) / 16)``.

    Returns
    -------
    numpy.ndarray
        Shape ``shape(shift) + (16,)``, float64.
    """
    s = np.asarray(shift, dtype=np.float64)
    i = np.arange(TILE, dtype=np.float64)
    return np.sin(np.pi * (i + 0.5 + s[..., None]) / TILE)


def _branch(q: int, axis: str) -> NDArray[np.float64]:
    bit = 1 if axis == "h" else 2
    return T_SIN if q & bit else T_COS


def clt_tiles(
    tiles: FloatArray, *, shift_x: FloatArray | float = 0.0, shift_y: FloatArray | float = 0.0
) -> FloatArray:
    """Forward CLT of a batch of 16x16 tiles (window, fold, DCT-IV/DST-IV) and phase rotation.

    Parameters
    ----------
    tiles
        ``(..., 16, 16)`` samples, rows = y.
    shift_x, shift_y
        Residual shifts s in pixels (broadcast against the batch shape). The window is
        shifted by s and the result rotated by s, so the output is the CLT of the image
        sampled on the grid ``left - s + j``, i.e. the content moves by +s.

    Returns
    -------
    numpy.ndarray
        ``(..., 4, 8, 8)`` quadrants CC, SC, CS, SS, each [kv][kh]; dtype of ``tiles``.
    """
    t = np.asarray(tiles)
    if t.shape[-2:] != (TILE, TILE):
        raise ValueError(f"tiles must have shape (..., 16, 16), got {t.shape}")
    dtype = t.dtype if t.dtype in (np.float32, np.float64) else np.dtype(np.float64)
    batch = t.shape[:-2]
    sx = np.broadcast_to(np.asarray(shift_x, dtype=np.float64), batch)
    sy = np.broadcast_to(np.asarray(shift_y, dtype=np.float64), batch)
    wx = window(sx).astype(dtype)
    wy = window(sy).astype(dtype)
    v = t.astype(dtype, copy=False) * wy[..., :, None] * wx[..., None, :]
    out = np.empty((*batch, 4, N, N), dtype=dtype)
    for q in range(4):
        th = _branch(q, "h").astype(dtype)
        tv = _branch(q, "v").astype(dtype)
        out[..., q, :, :] = tv @ v @ th.T
    return rotate(out, shift_x=sx, shift_y=sy)


def rotate(
    clt: FloatArray, *, shift_x: FloatArray | float, shift_y: FloatArray | float
) -> FloatArray:
    """Fractional shift of CLT tiles by phase rotation (horizontal, then vertical).

    Parameters
    ----------
    clt
        ``(..., 4, 8, 8)`` quadrants.
    shift_x, shift_y
        Shift in pixels, broadcast against the batch shape ``clt.shape[:-3]``.

    Returns
    -------
    numpy.ndarray
        Rotated quadrants, same shape and dtype.
    """
    c = np.asarray(clt)
    batch = c.shape[:-3]
    k = OMEGA
    sx = np.broadcast_to(np.asarray(shift_x, dtype=np.float64), batch)[..., None, None]
    sy = np.broadcast_to(np.asarray(shift_y, dtype=np.float64), batch)[..., None, None]
    ch, sh = np.cos(sx * k[None, :]).astype(c.dtype), np.sin(sx * k[None, :]).astype(c.dtype)
    cv, sv = np.cos(sy * k[:, None]).astype(c.dtype), np.sin(sy * k[:, None]).astype(c.dtype)
    cc, sc, cs, ss = (c[..., q, :, :] for q in range(4))
    cc, sc = cc * ch - sc * sh, sc * ch + cc * sh
    cs, ss = cs * ch - ss * sh, ss * ch + cs * sh
    cc, cs = cc * cv - cs * sv, cs * cv + cc * sv
    sc, ss = sc * cv - ss * sv, ss * cv + sc * sv
    return np.stack([cc, sc, cs, ss], axis=-3)


def iclt_tiles(clt: FloatArray) -> FloatArray:
    """Inverse CLT of tiles: transform, unfold, unshifted window; sum of quadrants / 4.

    Parameters
    ----------
    clt
        ``(..., 4, 8, 8)`` quadrants.

    Returns
    -------
    numpy.ndarray
        ``(..., 16, 16)`` windowed tiles, ready for overlap-add at stride 8.
    """
    c = np.asarray(clt)
    if c.shape[-3:] != (4, N, N):
        raise ValueError(f"clt must have shape (..., 4, 8, 8), got {c.shape}")
    dtype = c.dtype
    out = np.zeros((*c.shape[:-3], TILE, TILE), dtype=dtype)
    for q in range(4):
        # the fold is the transpose of the unfold and the 8-point transforms are self-inverse
        th = _branch(q, "h").astype(dtype)
        tv = _branch(q, "v").astype(dtype)
        out += tv.T @ c[..., q, :, :] @ th
    w = window(0.0).astype(dtype)
    return out * (0.25 * w[:, None] * w[None, :])


def to_complex(clt: FloatArray) -> tuple[ComplexArray, ComplexArray]:
    """Quadrants -> (z1, z2) complex form (see module docstring)."""
    cc, sc, cs, ss = (clt[..., q, :, :] for q in range(4))
    return (cc + ss) + 1j * (sc - cs), (cc - ss) + 1j * (sc + cs)


def from_complex(z1: ComplexArray, z2: ComplexArray) -> FloatArray:
    """(z1, z2) complex form -> quadrants CC, SC, CS, SS."""
    cc = 0.5 * (z1.real + z2.real)
    ss = 0.5 * (z1.real - z2.real)
    sc = 0.5 * (z1.imag + z2.imag)
    cs = 0.5 * (z2.imag - z1.imag)
    return np.stack([cc, sc, cs, ss], axis=-3)


def tile_grid(height: int, width: int) -> tuple[int, int]:
    """Tiles (tiles_y, tiles_x) of an image: one tile per 8x8 block, centre (8tx+4, 8ty+4)."""
    if height % N or width % N or height <= 0 or width <= 0:
        raise InputFormatError(f"image size {width}x{height} must be a positive multiple of 8")
    return height // N, width // N


def extract_tiles(image: FloatArray, *, bayer: bool = False) -> FloatArray:
    """All 16x16 tiles of an image at stride 8 (tile (tx, ty) covers 8tx-4 .. 8tx+11).

    Out-of-image samples repeat the nearest border sample of the same parity when
    ``bayer`` (so colours stay on their lattice), else the nearest border sample.

    Returns
    -------
    numpy.ndarray
        ``(tiles_y, tiles_x, 16, 16)``.
    """
    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"image must be 2-D, got shape {img.shape}")
    ty, tx = tile_grid(*img.shape)
    ys = _clamped_index(np.arange(-4, img.shape[0] + 4), img.shape[0], bayer=bayer)
    xs = _clamped_index(np.arange(-4, img.shape[1] + 4), img.shape[1], bayer=bayer)
    padded = img[np.ix_(ys, xs)]
    view = np.lib.stride_tricks.sliding_window_view(padded, (TILE, TILE))
    return view[::N, ::N][:ty, :tx].copy()


def _clamped_index(idx: NDArray[np.integer], size: int, *, bayer: bool) -> NDArray[np.intp]:
    if not bayer:
        return np.clip(idx, 0, size - 1).astype(np.intp)
    out = idx.copy()
    low = idx < 0
    high = idx >= size
    out[low] = idx[low] & 1
    out[high] = size - 2 + (idx[high] & 1)
    return out.astype(np.intp)


def overlap_add(tiles: FloatArray) -> FloatArray:
    """Overlap-add windowed 16x16 tiles at stride 8 back to an image.

    Parameters
    ----------
    tiles
        ``(tiles_y, tiles_x, 16, 16)``, tile (tx, ty) lands on pixels 8tx-4 .. 8tx+11.

    Returns
    -------
    numpy.ndarray
        ``(8 tiles_y, 8 tiles_x)`` image; the outer 4 pixels get only one tile per axis
        and are not reconstructed exactly.
    """
    t = np.asarray(tiles)
    ty, tx = t.shape[:2]
    # sum the four 8x8 quarters of each tile into an (ty+1, tx+1) grid of 8x8 blocks
    acc = np.zeros((ty + 1, N, tx + 1, N), dtype=t.dtype)
    for qy in (0, 1):
        for qx in (0, 1):
            acc[qy : qy + ty, :, qx : qx + tx, :] += t[
                :, :, qy * N : (qy + 1) * N, qx * N : (qx + 1) * N
            ].transpose(0, 2, 1, 3)
    full = acc.reshape((ty + 1) * N, (tx + 1) * N)
    return full[4 : 4 + ty * N, 4 : 4 + tx * N]


def clt_image(image: FloatArray, *, bayer: bool = False) -> FloatArray:
    """CLT of every tile of an image: ``(tiles_y, tiles_x, 4, 8, 8)``."""
    return clt_tiles(extract_tiles(image, bayer=bayer))


def iclt_image(clt: FloatArray) -> FloatArray:
    """Inverse of :func:`clt_image` by overlap-add (TDAC); exact away from the 4-pixel border."""
    return overlap_add(iclt_tiles(clt))
