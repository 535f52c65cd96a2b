"""Fused per-tile kernels of the tile processor, compiled by numba (host only).

NumPy makes one full pass over memory, and one temporary, per element-wise operation.
The two element-wise stretches of a pass are fused here into one loop each, around the
matrix products that NumPy and BLAS do well:

* :func:`gather_windowed`: each tile's cell-aligned footprint gathered from the cells of
  a camera and multiplied by its shifted window (separable: a row factor times a column
  factor), straight into the rows the transform products read;
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

import numba as nb
import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]
I64 = NDArray[np.int64]


_GATHER_SIGNATURE = nb.void(
    nb.float32[:, :, ::1],  # cells (rows, cols, planes)
    nb.int64[::1],  # first cell row of each footprint
    nb.int64[::1],  # first cell column
    nb.int64[::1],  # start parity along y (0 or 1; 0 for mono)
    nb.int64[::1],  # start parity along x
    nb.float32[:, ::1],  # (T, 2) cos, sin of the window shift along y
    nb.float32[:, ::1],  # (T, 2) along x
    nb.float32[:, :, :, ::1],  # row window factors (parity, planes, 2, span)
    nb.float32[:, :, :, ::1],  # column window factors (parity, planes, 2, span)
    nb.int64[:, ::1],  # first footprint row inside the tile (parity, planes)
    nb.int64[:, ::1],  # first footprint column inside the tile (parity, planes)
    nb.int64[::1],  # row of out for each tile
    nb.float32[:, ::1],  # out (T, planes * inner * inner)
)


@nb.njit(_GATHER_SIGNATURE, cache=True, nogil=True, fastmath=True, boundscheck=False)
def gather_windowed(
    cells: F32,
    rows: I64,
    cols: I64,
    par_y: I64,
    par_x: I64,
    win_y: F32,
    win_x: F32,
    rows_w: F32,
    cols_w: F32,
    first_y: I64,
    first_x: I64,
    dest: I64,
    out: F32,
) -> None:
    """Windowed samples of tiles: ``out[dest[t], (p, v, u)] = cells[r+v, c+u, p] wy[v] wx[u]``.

    Only the ``inner x inner`` samples of each plane that lie inside the tile are written
    (``v`` from ``first_y[parity, p]``, ``u`` from ``first_x[parity, p]``), so that with
    the rows grouped by start parity each group has one matrix per colour.

    Parameters
    ----------
    cells
        ``(rows, cols, planes)`` float32 cells of one camera
        (:func:`elphel_host.tp.clt.batch.image_cells`).
    rows, cols
        ``(T,)`` first cell of each tile's ``span x span`` footprint.
    par_y, par_x
        ``(T,)`` start parity of each tile (which window tables apply).
    win_y, win_x
        ``(T, 2)``: cos and sin of ``pi s / 16`` for the tile's shift s along the axis.
    rows_w, cols_w
        ``(parities, planes, 2, span)``: the sine and the cosine window on each plane's
        samples along the axis (zero outside the tile); the shifted window along an axis
        is ``cos * w[0] + sin * w[1]``.
    first_y, first_x
        ``(parities, planes)``: the first footprint sample inside the tile.
    dest
        ``(T,)``: the row of ``out`` that receives tile t.
    out
        ``(T, planes * inner * inner)`` float32, written plane by plane, row by row.
    """
    planes = cells.shape[2]
    inner = int(np.sqrt(out.shape[1] // planes))
    fy = np.empty(inner, dtype=np.float32)
    fx = np.empty(inner, dtype=np.float32)
    for t in range(rows.shape[0]):
        py, px = par_y[t], par_x[t]
        cy, sy, cx, sx = win_y[t, 0], win_y[t, 1], win_x[t, 0], win_x[t, 1]
        tile = out[dest[t]]
        for p in range(planes):
            v0, u0 = first_y[py, p], first_x[px, p]
            for j in range(inner):
                fy[j] = cy * rows_w[py, p, 0, v0 + j] + sy * rows_w[py, p, 1, v0 + j]
                fx[j] = cx * cols_w[px, p, 0, u0 + j] + sx * cols_w[px, p, 1, u0 + j]
            r0, c0 = rows[t] + v0, cols[t] + u0
            for v in range(inner):
                src = cells[r0 + v, c0 : c0 + inner, p]
                start = (p * inner + v) * inner
                dst = tile[start : start + inner]
                w = fy[v]
                for u in range(inner):
                    dst[u] = src[u] * w * fx[u]


@nb.njit(inline="always", cache=True, nogil=True, fastmath=True, boundscheck=False)
def _exponentials(cos1: np.float32, sin1: np.float32, out: F32) -> None:
    """``out[k] = exp(i (2k + 1) a)`` (re, im), k = 0..7, from ``cos a``, ``sin a``."""
    step_r = cos1 * cos1 - sin1 * sin1  # exp(2 i a)
    step_i = 2 * cos1 * sin1
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
        m = acc[0, 0, f] ** 2 + acc[0, 1, f] ** 2 + acc[1, 0, f] ** 2 + acc[1, 1, f] ** 2
        scale[f] = np.float32(1.0) / np.sqrt(np.float32(0.5) * m + fz2)
    for w in range(2):
        for f in range(nf):
            ra, ia = rot_a[w, 0, f], rot_a[w, 1, f]
            rb, ib = rot_b[w, 0, f], rot_b[w, 1, f]
            qr, qi = ra * rb + ia * ib, ra * ib - ia * rb  # conj(r_a) r_b
            pr, pi = acc[w, 0, f] * scale[f], acc[w, 1, f] * scale[f]
            out[w, 0, f] = pr * qr - pi * qi
            out[w, 1, f] = pr * qi + pi * qr


_PAIRS_SIGNATURE = nb.void(
    nb.float32[:, :, ::1],  # spectra (cameras, T, floats): per colour (which, re/im, f)
    nb.int64[:, ::1],  # row of spectra holding each tile (cameras, T)
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
    where: I64,
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
    where
        ``(cameras, T)``: the row of ``spectra[c]`` that holds tile t.
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
    ncam = rotation.shape[0]
    nf = kh.shape[0]
    ex = np.empty((8, 2), dtype=np.float32)
    ey = np.empty((8, 2), dtype=np.float32)
    rot = np.empty((ncam, 2, 2, nf), dtype=np.float32)
    acc = np.empty((2, 2, nf), dtype=np.float32)
    scale = np.empty(nf, dtype=np.float32)
    fz2 = fat_zero * fat_zero
    for t in range(rotation.shape[1]):
        for c in range(ncam):
            _exponentials(rotation[c, t, 0, 0], rotation[c, t, 0, 1], ex)
            _exponentials(rotation[c, t, 1, 0], rotation[c, t, 1, 1], ey)
            for f in range(nf):
                xr, xi = ex[kh[f], 0], ex[kh[f], 1]
                yr, yi = ey[kv[f], 0], ey[kv[f], 1]
                rot[c, 0, 0, f] = xr * yr - xi * yi
                rot[c, 0, 1, f] = xr * yi + xi * yr
                rot[c, 1, 0, f] = xr * yr + xi * yi
                rot[c, 1, 1, f] = xi * yr - xr * yi
        for p in range(pairs.shape[0]):
            a, b = pairs[p, 0], pairs[p, 1]
            _colour_sum(spectra[a, where[a, t]], spectra[b, where[b, t]], sizes, acc)
            _normalised(acc, rot[a], rot[b], fz2, scale, out[p, t])


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
