"""Fused per-tile kernels of the tile processor, compiled by numba (host only).

NumPy makes one full pass over memory, and one temporary, per element-wise operation,
and BLAS is slow on many tiny products. The per-tile stretches of a pass are fused here
into one loop each, around the larger matrix products that BLAS does well:

* :func:`tile_spectra`: each tile's samples of every Bayer plane gathered from a
  camera's image (border pixels repeated outside it), multiplied by its shifted window
  and transformed, along the rows then down the columns, into its colour spectra;
* :func:`rotated_pair_products`: the pair products summed over colours (first camera
  conjugated), the fat-zero normalisation and both cameras' phase rotations, per tile;
* :func:`lens_pixels` and :func:`lens_windows`: where a calibrated camera sees each tile
  (:meth:`elphel_host.tp.calibrated.CalibratedGeometry.pixels`, the same operations in
  the same order, so the same float64 results), one loop instead of some forty NumPy
  passes per chunk and camera.

The kernels are compiled when this module is imported (explicit signatures, cached on
disk by numba), release the GIL and run on the tile processor's worker threads.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, cast

import numba as nb
import numpy as np
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic
from numpy.typing import NDArray

F32 = NDArray[np.float32]
I64 = NDArray[np.int64]
U64 = NDArray[np.uint64]


def _stack_typing(element: types.Type) -> Callable[[object, types.Type], object]:
    """Typing and code of a stack allocation of n ``element`` values (n a literal int)."""

    def typing(typingctx: object, size: types.Type) -> object:
        if not isinstance(size, types.IntegerLiteral):
            return None

        def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
            count = context.get_constant(types.intp, size.literal_value)
            return cgutils.alloca_once(builder, context.get_value_type(element), size=count)

        return types.CPointer(element)(size), codegen

    return typing


#: ``_stack_floats(n)`` in a kernel: a pointer to n float32 on the kernel's stack (n a
#: literal int). Scratch on the stack provably aliases no argument, so the compiler keeps
#: a tile's partial sums in vector registers; heap scratch (``np.empty``) could alias
#: ``out``, and the compiler then falls back to scalar loads and stores.
_stack_floats = cast(
    Callable[[int], Any], intrinsic(prefer_literal=True)(_stack_typing(types.float32))
)
#: ``_stack_doubles(n)``: the same for n float64.
_stack_doubles = cast(
    Callable[[int], Any], intrinsic(prefer_literal=True)(_stack_typing(types.float64))
)
#: ``_stack_ints(n)``: the same for n int64.
_stack_ints = cast(Callable[[int], Any], intrinsic(prefer_literal=True)(_stack_typing(types.int64)))


# Products without reassociation: the compiler then vectorises the 16 independent sums
# of a tile row (one vector register) instead of each sum over its 8 terms.
_SUMS = {"contract", "nnan", "ninf", "nsz", "arcp"}


@nb.njit(inline="always", cache=True, nogil=True, fastmath=_SUMS, boundscheck=False)
def _sum8(m: F32, r: int, s: tuple[float, ...], out: F32, row: int, accumulate: bool) -> None:
    """``out[row, j] (+)= sum_k s[k] m[r + k, j]``, k < 8, for the 16 columns j of ``m``."""
    s0, s1, s2, s3, s4, s5, s6, s7 = s
    for j in range(16):
        x = (
            s0 * m[r, j]
            + s1 * m[r + 1, j]
            + s2 * m[r + 2, j]
            + s3 * m[r + 3, j]
            + s4 * m[r + 4, j]
            + s5 * m[r + 5, j]
            + s6 * m[r + 6, j]
            + s7 * m[r + 7, j]
        )
        if accumulate:
            out[row, j] += x
        else:
            out[row, j] = x


@nb.njit(inline="always", cache=True, nogil=True, fastmath=_SUMS, boundscheck=False)
def _tile_rows(
    image: F32,
    rows: I64,
    cols: I64,
    wy: F32,
    fx: F32,
    basis: F32,
    out: F32,
    first: int,
    inner: int,
) -> None:
    """Rows ``first + v`` of ``out``: one plane's windowed samples times the row basis.

    ``out[first + v, j] = wy[v] sum_u image[rows[v], cols[u]] fx[u] basis[u, j]``, v and
    u below ``inner``.
    """
    for v in range(inner):
        src = image[rows[v]]
        w = wy[v]
        for h in range(0, inner, 8):
            s = (
                w * fx[h] * src[cols[h]],
                w * fx[h + 1] * src[cols[h + 1]],
                w * fx[h + 2] * src[cols[h + 2]],
                w * fx[h + 3] * src[cols[h + 3]],
                w * fx[h + 4] * src[cols[h + 4]],
                w * fx[h + 5] * src[cols[h + 5]],
                w * fx[h + 6] * src[cols[h + 6]],
                w * fx[h + 7] * src[cols[h + 7]],
            )
            _sum8(basis, h, s, out, first + v, h > 0)


@nb.njit(inline="always", cache=True, nogil=True, boundscheck=False)
def _plane_samples(
    first: int, pad: int, cells: int, cell: int, offset: int, inner: int, out: I64
) -> None:
    """Image rows (or columns) of one plane's ``inner`` samples from padded cell ``first``.

    The cells of the padding repeat the border cell: ``cell * clip(first + v - pad, 0,
    cells - 1) + offset``, the plane's pixel of the same Bayer parity at the border.
    """
    for v in range(inner):
        out[v] = cell * min(max(first + v - pad, 0), cells - 1) + offset


@nb.njit(inline="always", cache=True, nogil=True, fastmath=_SUMS, boundscheck=False)
def _tile_columns(
    y: F32, first: int, basis: F32, kv_count: int, za: F32, zb: F32, add: bool, inner: int
) -> None:
    """Column transform of one plane's rows ``y[first:first + inner]`` into ``za``, ``zb``.

    ``za[kv] (+)= sum_v Re(E[kv, v]) y[first + v]``, ``zb`` the same with ``Im``.
    """
    for k in range(kv_count):
        a, b = basis[0, k], basis[1, k]
        for h in range(0, inner, 8):
            sa = (a[h], a[h + 1], a[h + 2], a[h + 3], a[h + 4], a[h + 5], a[h + 6], a[h + 7])
            sb = (b[h], b[h + 1], b[h + 2], b[h + 3], b[h + 4], b[h + 5], b[h + 6], b[h + 7])
            _sum8(y, first + h, sa, za, k, add or h > 0)
            _sum8(y, first + h, sb, zb, k, add or h > 0)


@nb.njit(inline="always", cache=True, nogil=True, fastmath=_SUMS, boundscheck=False)
def _store_colour(fa: F32, fb: F32, positions: U64, n: int, root: F32, out: F32, base: int) -> None:
    """One colour's ``(which, re/im, f)`` from the column sums (flat ``za``, ``zb``).

    With ``E = a + ib`` along y and ``Y = c + id`` the row transform: ``za = (sum a c |
    sum a d)``, ``zb = (sum b c | sum b d)``, so ``E Y`` (z2) and ``conj(E) Y`` (z1) are
    their sums and differences.
    """
    for f in range(n):
        i = positions[f]
        ac, ad, bc, bd = fa[i], fa[i + 8], fb[i], fb[i + 8]
        out[base + f] = root[0, f] * (ac - bd)
        out[base + n + f] = root[0, f] * (ad + bc)
        out[base + 2 * n + f] = root[1, f] * (ac + bd)
        out[base + 3 * n + f] = root[1, f] * (ad - bc)


#: ``pi / 16``: the window's phase per pixel of shift.
_WINDOW_ANGLE = np.pi / 16


@nb.njit(inline="always", cache=True, nogil=True, fastmath=_SUMS, boundscheck=False)
def _all_tiles(
    image: F32,
    cell_at: I64,
    pad: int,
    at: I64,
    shifts: NDArray[np.float64],
    window_y: F32,
    window_x: F32,
    row_basis: F32,
    col_basis: F32,
    first_y: I64,
    first_x: I64,
    colours: I64,
    positions: U64,
    roots: F32,
    out: F32,
    planes: int,
    inner: int,
    cell: int,
) -> None:
    """:func:`tile_spectra` for ``planes`` planes of ``inner x inner`` samples (constants)."""
    y = nb.carray(_stack_floats(1024), (64, 16))  # (plane, v) rows of the row transform
    wy = nb.carray(_stack_floats(16), (16,))
    fx = nb.carray(_stack_floats(16), (16,))
    rows = nb.carray(_stack_ints(16), (16,))
    cols = nb.carray(_stack_ints(16), (16,))
    h, w = image.shape[0] // cell, image.shape[1] // cell
    pa, pb = _stack_floats(128), _stack_floats(128)
    za, zb = nb.carray(pa, (8, 16)), nb.carray(pb, (8, 16))
    fa, fb = nb.carray(pa, (128,)), nb.carray(pb, (128,))
    for t in range(at.shape[1]):
        py, px = at[2, t], at[3, t]
        ay, ax = _WINDOW_ANGLE * shifts[0, t], _WINDOW_ANGLE * shifts[1, t]
        cy, sy = np.float32(np.cos(ay)), np.float32(np.sin(ay))
        cx, sx = np.float32(np.cos(ax)), np.float32(np.sin(ax))
        for p in range(planes):
            for v in range(inner):
                wy[v] = cy * window_y[py, p, 0, v] + sy * window_y[py, p, 1, v]
                fx[v] = cx * window_x[px, p, 0, v] + sx * window_x[px, p, 1, v]
            _plane_samples(at[0, t] + first_y[py, p], pad, h, cell, cell_at[0, p], inner, rows)
            _plane_samples(at[1, t] + first_x[px, p], pad, w, cell, cell_at[1, p], inner, cols)
            _tile_rows(image, rows, cols, wy, fx, row_basis[px, p], y, p * inner, inner)
        base = 0
        for c in range(colours.shape[0]):
            p0, p1, n, kvs = colours[c, 0], colours[c, 1], colours[c, 2], colours[c, 3]
            for p in range(p0, p1):
                _tile_columns(y, p * inner, col_basis[py, p], kvs, za, zb, p > p0, inner)
            _store_colour(fa, fb, positions, n, roots[c], out[t], base)
            base += 4 * n


_SPECTRA_SIGNATURE = nb.void(
    nb.float32[:, ::1],  # image (H, W)
    nb.int64[:, ::1],  # (2, planes): row, column of each plane's pixel in its cell
    nb.int64,  # padding, cells
    nb.int64[:, ::1],  # (4, T): first cell row, first cell column, parity y, parity x
    nb.float64[:, ::1],  # (2, T): the window's shift along y, along x
    nb.float32[:, :, :, ::1],  # window along y (parity, planes, 2, inner)
    nb.float32[:, :, :, ::1],  # window along x (parity, planes, 2, inner)
    nb.float32[:, :, :, ::1],  # row basis (parity, planes, inner, 16)
    nb.float32[:, :, :, :, ::1],  # column basis (parity, planes, 2, 8, inner)
    nb.int64[:, ::1],  # first sample inside the tile along y (parity, planes)
    nb.int64[:, ::1],  # along x
    nb.int64[:, ::1],  # per colour: first plane, end plane, frequencies, kv count
    nb.uint64[::1],  # (F,) position 16 kv + kh of each frequency in the column sums
    nb.float32[:, :, ::1],  # (colours, which, F) square root of the colour weights
    nb.float32[:, ::1],  # out (T, 4 sum F)
)


@nb.njit(_SPECTRA_SIGNATURE, cache=True, nogil=True, fastmath=_SUMS, boundscheck=False)
def tile_spectra(
    image: F32,
    cell_at: I64,
    pad: int,
    at: I64,
    shifts: NDArray[np.float64],
    window_y: F32,
    window_x: F32,
    row_basis: F32,
    col_basis: F32,
    first_y: I64,
    first_x: I64,
    colours: I64,
    positions: U64,
    roots: F32,
    out: F32,
) -> None:
    """Colour spectra of tiles by the separable transform, gathered and windowed on the way.

    Per tile and plane: the samples inside the tile, read from ``image`` (a plane is
    the pixel ``cell_at`` of each cell; the ``pad`` cells around the image the footprint
    cells ``at`` count from repeat the border cell), times the shifted window along each
    axis (``cos(pi s / 16) w[0] + sin(pi s / 16) w[1]`` for the tile's ``shifts`` s),
    transformed along the rows (``row_basis``: ``(re | im)`` of the basis at each sample
    for kh 0..7), then down the columns (``col_basis``: re and im for kv 0..7) and summed
    over each colour's planes; the square root of the colour weight (``roots``) is
    applied on the way out. ``at`` also holds each tile's start parity, which indexes
    the transform's tables (:class:`elphel_host.tp.clt.batch.CameraTransform`);
    ``colours``: per colour its first and end plane, frequencies and kv count;
    ``positions``: where each frequency is in the column sums. Row t of ``out``, ``(T, 4
    sum F)``, is tile t: its colours one after the other, each ``(which, re/im, f)``.
    """
    if row_basis.shape[2] == 8:  # Bayer: four 8x8 planes
        _all_tiles(
            image,
            cell_at,
            pad,
            at,
            shifts,
            window_y,
            window_x,
            row_basis,
            col_basis,
            first_y,
            first_x,
            colours,
            positions,
            roots,
            out,
            4,
            8,
            2,
        )
    else:  # mono: one 16x16 plane
        _all_tiles(
            image,
            cell_at,
            pad,
            at,
            shifts,
            window_y,
            window_x,
            row_basis,
            col_basis,
            first_y,
            first_x,
            colours,
            positions,
            roots,
            out,
            1,
            16,
            1,
        )


@nb.njit(inline="always", cache=True, nogil=True, fastmath=True, boundscheck=False)
def _exponentials(cos1: np.float32, sin1: np.float32, out: F32) -> None:
    """``out[k] = exp(i (2k + 1) a)`` (re, im), k = 0..7, from ``cos a``, ``sin a``."""
    step_r = cos1 * cos1 - sin1 * sin1  # exp(2 i a)
    step_i = np.float32(2.0) * cos1 * sin1
    r, i = cos1, sin1
    for k in range(8):
        out[k, 0] = r
        out[k, 1] = i
        r, i = r * step_r - i * step_i, r * step_i + i * step_r


@nb.njit(inline="always", cache=True, nogil=True, fastmath=True, boundscheck=False)
def _colour_sum(sa: F32, sb: F32, sizes: I64, acc: F32) -> None:
    """``acc[which, re/im, f] = sum over colours of conj(A) B`` (planar colour blocks).

    The last colour (green, or mono) holds every frequency; the others a prefix.
    """
    ncol = sizes.shape[0]
    base = 4 * (np.sum(sizes) - sizes[ncol - 1])
    for col in range(ncol - 1, -1, -1):
        n = sizes[col]
        for w in range(2):
            ar = sa[base + 2 * w * n : base + (2 * w + 1) * n]
            ai = sa[base + (2 * w + 1) * n : base + (2 * w + 2) * n]
            br = sb[base + 2 * w * n : base + (2 * w + 1) * n]
            bi = sb[base + (2 * w + 1) * n : base + (2 * w + 2) * n]
            re, im = acc[w, 0], acc[w, 1]
            if col == ncol - 1:
                for f in range(n):
                    re[f] = ar[f] * br[f] + ai[f] * bi[f]
                    im[f] = ar[f] * bi[f] - ai[f] * br[f]
            else:
                for f in range(n):
                    re[f] += ar[f] * br[f] + ai[f] * bi[f]
                    im[f] += ar[f] * bi[f] - ai[f] * br[f]
        if col > 0:
            base -= 4 * sizes[col - 1]


@nb.njit(inline="always", cache=True, nogil=True, fastmath=True, boundscheck=False)
def _normalised(acc: F32, rot_a: F32, rot_b: F32, fz2: np.float32, scale: F32, out: F32) -> None:
    """``out[which, re/im, f] = acc conj(rot_a) rot_b / sqrt(fz2 + mean |acc|^2 over which)``."""
    nf = acc.shape[2]
    for f in range(nf):
        a, b, c, d = acc[0, 0, f], acc[0, 1, f], acc[1, 0, f], acc[1, 1, f]
        m = a * a + b * b + c * c + d * d
        scale[f] = np.float32(1.0) / np.sqrt(np.float32(0.5) * m + fz2)
    for w in range(2):
        for f in range(nf):
            ra, ia = rot_a[w, 0, f], rot_a[w, 1, f]
            rb, ib = rot_b[w, 0, f], rot_b[w, 1, f]
            qr, qi = ra * rb + ia * ib, ra * ib - ia * rb  # conj(r_a) r_b
            pr, pi = acc[w, 0, f] * scale[f], acc[w, 1, f] * scale[f]
            out[w, 0, f] = pr * qr - pi * qi
            out[w, 1, f] = pr * qi + pi * qr


@nb.njit(inline="always", cache=True, nogil=True, fastmath=True, boundscheck=False)
def _rotations(rotation: F32, t: int, kh: I64, kv: I64, rot: F32) -> None:
    """``rot[c, which, re/im, f]``: camera c's phase rotation of tile t at each frequency."""
    ex = nb.carray(_stack_floats(16), (8, 2))
    ey = nb.carray(_stack_floats(16), (8, 2))
    for c in range(rotation.shape[0]):
        _exponentials(rotation[c, t, 0, 0], rotation[c, t, 0, 1], ex)
        _exponentials(rotation[c, t, 1, 0], rotation[c, t, 1, 1], ey)
        for f in range(kh.shape[0]):
            xr, xi = ex[kh[f], 0], ex[kh[f], 1]
            yr, yi = ey[kv[f], 0], ey[kv[f], 1]
            rot[c, 0, 0, f] = xr * yr - xi * yi
            rot[c, 0, 1, f] = xr * yi + xi * yr
            rot[c, 1, 0, f] = xr * yr + xi * yi
            rot[c, 1, 1, f] = xi * yr - xr * yi


_PAIRS_SIGNATURE = nb.void(
    nb.float32[:, :, ::1],  # spectra (cameras, T, floats): per colour (which, re/im, f)
    nb.float32[:, :, :, ::1],  # rotation (cameras, T, 2 axes, cos/sin) of pi s / 16
    nb.int64[:, ::1],  # pairs (P, 2)
    nb.int64[::1],  # kh (F,)
    nb.int64[::1],  # kv (F,)
    nb.int64[::1],  # colour sizes (colours,)
    nb.float32,  # fat zero
    nb.float32[:, :, :, :, ::1],  # out (P, T, which, re/im, F)
)


@nb.njit(_PAIRS_SIGNATURE, cache=True, nogil=True, fastmath=True, boundscheck=False)
def rotated_pair_products(
    spectra: F32,
    rotation: F32,
    pairs: I64,
    kh: I64,
    kv: I64,
    sizes: I64,
    fat_zero: np.float32,
    out: F32,
) -> None:
    """Normalised pair products of rotated spectra: ``out[p, t, which, re/im, f]``.

    For pair (a, b): ``P = sum_c conj(A_c) B_c`` over colours c holding frequency f,
    divided by ``sqrt(fat_zero^2 + (|P_z2|^2 + |P_z1|^2) / 2)`` and multiplied by
    ``conj(r_a) r_b``, where ``r`` is the camera's rotation by its shift (x, y):
    ``exp(i (x w(kh) + y w(kv)))`` for z2 (which 0) and ``exp(i (x w(kh) - y w(kv)))``
    for z1, ``w(k) = pi (2k + 1) / 16``. Equal to rotating each camera's colour spectra,
    then :func:`~elphel_host.tp.correlation.compact_pair_products` and
    :func:`~elphel_host.tp.correlation.normalise`.

    Parameters
    ----------
    spectra
        ``(cameras, T, 4 sum(sizes))``: per camera and tile its colours one after the
        other, each ``(which, re/im, f)`` on its first ``sizes[c]`` frequencies.
    rotation
        ``(cameras, T, 2, 2)``: per axis (x, y) the cos and sin of ``pi s / 16`` for the
        camera's rotation shift s.
    pairs
        ``(P, 2)`` first and second camera of each pair.
    kh, kv
        ``(F,)`` frequency indices of the kept frequencies.
    sizes
        ``(colours,)`` frequencies of each colour (a prefix of the F kept ones).
    fat_zero
        Fat zero of the normalisation.
    out
        ``(P, T, 2, 2, F)`` float32: (which, re/im, f) per pair and tile.
    """
    nf = kh.shape[0]
    # scratch on the stack (see _stack_floats): at most 4 cameras and 64 frequencies
    rot = nb.carray(_stack_floats(1024), (rotation.shape[0], 2, 2, nf))
    acc = nb.carray(_stack_floats(256), (2, 2, nf))
    scale = nb.carray(_stack_floats(64), (nf,))
    fz2 = fat_zero * fat_zero
    for t in range(rotation.shape[1]):
        _rotations(rotation, t, kh, kv, rot)
        for p in range(pairs.shape[0]):
            a, b = pairs[p, 0], pairs[p, 1]
            _colour_sum(spectra[a, t], spectra[b, t], sizes, acc)
            _normalised(acc, rot[a], rot[b], fz2, scale, out[p, t])


@nb.njit(inline="always", cache=True, nogil=True, boundscheck=False)
def _group_profiles(
    prof: F32, means: F32, envelope: F32, scratch: F32, combined: F32, levelled: F32
) -> None:
    """One tile's pair profiles averaged per group (``combined``), and levelled (lags).

    ``scratch``: ``(pairs, lags)`` for each pair's profile over its envelope.
    """
    npairs, nl = envelope.shape
    for p in range(npairs):
        for s in range(nl):
            scratch[p, s] = prof[p, s] / envelope[p, s]
    for g in range(means.shape[0]):
        for s in range(prof.shape[1]):
            combined[g, s] = np.float32(0.0)
        for s in range(nl):
            levelled[g, s] = np.float32(0.0)
        for p in range(npairs):
            m = means[g, p]
            if m != 0:
                for s in range(prof.shape[1]):
                    combined[g, s] += m * prof[p, s]
                for s in range(nl):
                    levelled[g, s] += m * scratch[p, s]


@nb.njit(inline="always", cache=True, nogil=True, boundscheck=False)
def _integer_max(select: F32, lags: NDArray[np.float64], lag_min: float) -> int:
    """``numpy.argmax`` of ``select`` over the lags at or above ``lag_min - 0.5``."""
    best, at = -np.inf, 0
    for i in range(lags.shape[0]):
        v = -np.inf if lags[i] < lag_min - 0.5 else select[i]
        if np.isnan(v):
            return i
        if v > best:
            best, at = v, i
    return at


@nb.njit(inline="always", cache=True, nogil=True, boundscheck=False)
def _parabola(c: F32, nl: int, idx: int) -> tuple[float, np.float32]:
    """Fraction and value of the parabola's peak through ``c[idx]`` and its neighbours."""
    inner = min(max(idx, 1), nl - 2)
    c0, cm, cp = c[inner], c[inner - 1], c[inner + 1]
    curv = cm + cp - np.float32(2.0) * c0
    if curv < 0 and idx == inner:
        frac = min(max(np.float32(0.5) * (cm - cp) / curv, np.float32(-0.5)), np.float32(0.5))
        return frac, c0 - np.float32(0.25) * (cm - cp) * frac
    return 0.0, c[idx]


@nb.njit(inline="always", cache=True, nogil=True, boundscheck=False)
def _gaussian(
    c: F32, nl: int, deriv_lags: NDArray[np.float64], lag: float, idx: int
) -> tuple[bool, float, np.float32]:
    """Where the log-parabola fit from the derivatives at ``lag`` holds, its step and peak."""
    nd = deriv_lags.shape[0]
    for j in range(nd):
        if deriv_lags[j] == lag:
            g, g1, g2 = c[idx], c[nl + j], c[nl + nd + j]
            den = g * g2 - g1 * g1
            if g > 0 and den < 0:
                step = -g * g1 / den
                if abs(step) <= 1.0:
                    return True, step, g * np.float32(np.exp(np.float32(0.5) * g1 * step / g))
            break
    return False, 0.0, np.float32(0.0)


@nb.njit(inline="always", cache=True, nogil=True, boundscheck=False)
def _centroid(c: F32, nl: int, idx: int, taper: NDArray[np.float64]) -> float:
    """Offset of the centre of mass of ``c``'s positive values around ``idx`` (tapered)."""
    half = taper.shape[0] // 2
    s0, s1 = 0.0, 0.0
    for k in range(-half, half + 1):
        i = idx + k
        if 0 <= i < nl:
            w = max(np.float64(c[i]), 0.0) * taper[k + half]
            s0 += w
            s1 += w * k
    return s1 / s0 if s0 > 0 else 0.0


_PEAKS_SIGNATURE = nb.void(
    nb.float32[:, :, ::1],  # pair profiles (T, P, S): at the lags, then derivatives 1 and 2
    nb.float32[:, ::1],  # group means (G, P)
    nb.float32[:, ::1],  # window envelope (P, L)
    nb.float64[::1],  # lags (L,)
    nb.float64[::1],  # deriv lags (D,)
    nb.float64[::1],  # centroid taper (2 h + 1,)
    nb.float64[::1],  # lag_min (T,)
    nb.float32[:, ::1],  # out: residual (T, G)
    nb.float32[:, ::1],  # out: strength (T, G)
    nb.float32[::1],  # out: centroid residual of group 0 (T,)
    nb.float32[:, ::1],  # out: levelled profile of group 0 (T, L)
)


@nb.njit(_PEAKS_SIGNATURE, cache=True, nogil=True, boundscheck=False)
def correlation_peaks(
    profiles: F32,
    means: F32,
    envelope: F32,
    lags: NDArray[np.float64],
    deriv_lags: NDArray[np.float64],
    taper: NDArray[np.float64],
    lag_min: NDArray[np.float64],
    residual: F32,
    strength: F32,
    centroid: F32,
    levelled0: F32,
) -> None:
    """Per tile and group of pairs the sub-pixel correlation maximum, in one pass.

    The compiled form of averaging the pair profiles over each group (``means``), the
    integer maximum of the levelled profile (each pair's divided by its ``envelope``)
    above ``lag_min - 0.5``, and :func:`elphel_host.tp.correlation.subpixel_max` and
    :func:`~elphel_host.tp.correlation.windowed_centroid` there (their NumPy reference),
    with the same float32 and float64 steps.
    """
    ng, nl = means.shape[0], lags.shape[0]
    comb = np.empty((ng, profiles.shape[2]), dtype=np.float32)
    lev = np.empty((ng, nl), dtype=np.float32)
    scratch = np.empty(envelope.shape, dtype=np.float32)
    for t in range(profiles.shape[0]):
        _group_profiles(profiles[t], means, envelope, scratch, comb, lev)
        for g in range(ng):
            c = comb[g]
            idx = _integer_max(lev[g], lags, lag_min[t])
            frac, value = _parabola(c, nl, idx)
            pos = lags[0] + idx + frac
            good, step, peak = _gaussian(c, nl, deriv_lags, lags[idx], idx)
            if good:
                pos, value = lags[idx] + step, peak
            residual[t, g] = max(pos, lag_min[t] - 0.5)
            strength[t, g] = value
            if g == 0:
                centroid[t] = lags[0] + idx + _centroid(c, nl, idx, taper)
        levelled0[t] = lev[0]


@nb.njit(inline="always", cache=True, nogil=True, boundscheck=False)
def _box_profile(levelled: F32, y: int, x: int, out: NDArray[np.float64]) -> None:
    """Sum of the finite ``levelled[y, x]`` profiles of the 3x3 tiles around (y, x).

    Edge tiles repeated; -inf where the tile's own value is not finite.
    """
    ty, tx, nl = levelled.shape
    for k in range(nl):
        out[k] = 0.0
    for dy in range(-1, 2):
        row = levelled[min(max(y + dy, 0), ty - 1)]
        for dx in range(-1, 2):
            src = row[min(max(x + dx, 0), tx - 1)]
            for k in range(nl):
                v = np.float64(src[k])
                out[k] += v if np.isfinite(v) else 0.0
    own = levelled[y, x]
    for k in range(nl):
        if not np.isfinite(own[k]):
            out[k] = -np.inf


_NEIGHBOURHOOD_SIGNATURE = nb.void(
    nb.float32[:, :, ::1],  # levelled correlation (ty, tx, L)
    nb.float32[:, ::1],  # each tile's own residual (ty, tx)
    nb.float64[::1],  # lags (L,)
    nb.float64[:, ::1],  # out: residual (ty, tx)
    nb.float64[:, ::1],  # out: peak value (ty, tx)
)


@nb.njit(_NEIGHBOURHOOD_SIGNATURE, cache=True, nogil=True, boundscheck=False)
def neighbourhood_peaks(
    levelled: F32,
    own: F32,
    lags: NDArray[np.float64],
    residual: NDArray[np.float64],
    peak: NDArray[np.float64],
) -> None:
    """Per tile the maximum of its 3x3 neighbourhood's summed levelled correlation.

    Its lag plus the parabola's fraction through it and its neighbours (within +-0.5),
    or the tile's ``own`` residual where that is within 1 px of it; ``peak`` the summed
    value there (the first pass of :func:`elphel_host.tp.processor.disparity_map`).
    """
    nl = lags.shape[0]
    smooth = nb.carray(_stack_doubles(64), (nl,))  # at most 64 lags
    for y in range(levelled.shape[0]):
        for x in range(levelled.shape[1]):
            _box_profile(levelled, y, x, smooth)
            i = 0
            for k in range(1, nl):
                if smooth[k] > smooth[i]:
                    i = k
            top, lo, hi = smooth[i], smooth[max(i - 1, 0)], smooth[min(i + 1, nl - 1)]
            curv = lo + hi - 2 * top
            frac = 0.5 * (lo - hi) / curv if np.isfinite(curv) and curv < 0 else 0.0
            r = lags[i] + min(max(frac, -0.5), 0.5)
            near = abs(np.float64(own[y, x]) - r) <= 1.0
            residual[y, x] = own[y, x] if near else r
            peak[y, x] = top


#: The calibrated camera of :func:`lens_pixels`, packed by
#: :meth:`elphel_host.tp.calibrated.CalibratedGeometry.lens_parameters`.
LENS_PARAMETERS = (
    *("half_width", "half_height", "focal_px", "focal_px_times_baseline_mm"),
    *("offset_x_mm", "offset_y_mm", "offset_z_mm"),
    *(f"r{i}{j}" for i in range(3) for j in range(3)),
    *("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    *("fx", "fy", "cx", "cy"),
)


@nb.njit(inline="always", cache=True, nogil=True, boundscheck=False, error_model="numpy")
def _lens_point(
    cx: float, cy: float, disparity: float, m: NDArray[np.float64]
) -> tuple[float, float]:
    """Continuous pixel of one tile centre at one disparity (no fastmath: exact float64).

    ``m``: the camera's :data:`LENS_PARAMETERS`.
    """
    x = (cx - m[0]) / m[2]
    y = (cy - m[1]) / m[2]
    s = disparity / m[3]
    r0, r1, r2 = x - s * m[4], y - s * m[5], 1.0 - s * m[6]
    xc = m[7] * r0 + m[8] * r1 + m[9] * r2
    yc = m[10] * r0 + m[11] * r1 + m[12] * r2
    zc = m[13] * r0 + m[14] * r1 + m[15] * r2
    u, v = xc / zc, yc / zc
    k1, k2, p1, p2, k3, k4, k5, k6 = m[16], m[17], m[18], m[19], m[20], m[21], m[22], m[23]
    rr = u * u + v * v
    radial = (1 + rr * (k1 + rr * (k2 + rr * k3))) / (1 + rr * (k4 + rr * (k5 + rr * k6)))
    ud = u * radial + 2 * p1 * u * v + p2 * (rr + 2 * u * u)
    vd = v * radial + p1 * (rr + 2 * v * v) + 2 * p2 * u * v
    return m[24] * ud + m[26] + 0.5, m[25] * vd + m[27] + 0.5


_LENS_SIGNATURE = nb.void(
    nb.float64[::1],  # tile centres x (T,)
    nb.float64[::1],  # tile centres y (T,)
    nb.float64[::1],  # disparity (T,)
    nb.float64[::1],  # the camera (LENS_PARAMETERS)
    nb.float64[:, ::1],  # out (2, T): x, y
)


@nb.njit(_LENS_SIGNATURE, cache=True, nogil=True, boundscheck=False, error_model="numpy")
def lens_pixels(
    cx: NDArray[np.float64],
    cy: NDArray[np.float64],
    disparity: NDArray[np.float64],
    model: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """Continuous pixel (x, y) of each virtual-camera point (cx, cy) at its disparity.

    The calibrated geometry's undistort, shift by the disparity, rotation and distortion
    (:meth:`elphel_host.tp.calibrated.CalibratedGeometry.pixels`); ``model`` holds one
    camera's :data:`LENS_PARAMETERS`.
    """
    for t in range(cx.shape[0]):
        out[0, t], out[1, t] = _lens_point(cx[t], cy[t], disparity[t], model)


_WINDOWS_SIGNATURE = nb.void(
    nb.float64[::1],  # tile centres x (T,)
    nb.float64[::1],  # tile centres y (T,)
    nb.float64[::1],  # disparity (T,)
    nb.float64[::1],  # the camera (LENS_PARAMETERS)
    nb.int64[:, ::1],  # out (2, T): first pixel of the window along x, along y
    nb.float64[:, ::1],  # out (2, T): residual shift along x, along y
)


@nb.njit(_WINDOWS_SIGNATURE, cache=True, nogil=True, boundscheck=False, error_model="numpy")
def lens_windows(
    cx: NDArray[np.float64],
    cy: NDArray[np.float64],
    disparity: NDArray[np.float64],
    model: NDArray[np.float64],
    first: NDArray[np.int64],
    shift: NDArray[np.float64],
) -> None:
    """:func:`lens_pixels`, then the 16-sample window there along each axis.

    As :func:`elphel_host.tp.geometry.window_at`: ``first = floor(p - 8 + 0.5)`` and
    ``shift = first - (p - 8)`` for the continuous pixel p. Two loops, each of which
    the compiler vectorises.
    """
    for t in range(cx.shape[0]):
        shift[0, t], shift[1, t] = _lens_point(cx[t], cy[t], disparity[t], model)
    for a in range(2):
        for t in range(cx.shape[0]):
            p = shift[a, t] - 8.0
            left = np.floor(p + 0.5)
            first[a, t] = np.int64(left)
            shift[a, t] = left - p
