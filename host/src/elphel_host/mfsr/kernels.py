"""Fused element-wise kernels of the Fourier solver, compiled by numba (host only).

NumPy makes one pass over memory, and one temporary, per element-wise operation; the
solver's spectra are large (a full-size frame's is 10 MB) and each is touched by several
such operations in a row. Each kernel here is one pass over a band of rows:

* :func:`accumulate`: frames' spectra times their frequency ramps and couplings, added
  to every alias of the right-hand side;
* :func:`predict`: one frame's model spectrum, the aliases combined by the frame's
  coupling and multiplied by its (conjugate) ramp;
* :func:`place`: an alias block scattered into the HR spectrum;
* :func:`pseudo_data`: a frame's Huber pseudo-data and a sample of its residual;
* :func:`shift_normal_equations`: the sums of a frame's shift refinement;
* :func:`squared_residual`: a prediction's squared error on a rectangle.

Real images' spectra are in OpenCV's packed layout (CCS, see :func:`packed_rfft2`):
OpenCV's real transforms take half the time of SciPy's on these sizes, and the kernels
read and write that layout directly, so that no pass converts it.

Each pixel's arithmetic does not depend on how the rows are split: the result is the
same on any number of threads. The kernels release the GIL and are compiled on first
use (explicit signatures, cached on disk by numba).
"""

from __future__ import annotations

from typing import Any

import cv2
import numba as nb
import numpy as np
from numpy.typing import NDArray

C64 = NDArray[np.complex64]
F32 = NDArray[np.float32]
I64 = NDArray[np.int64]

# Complex arrays go in as float32 views (re, im interleaved): the compiler vectorises
# the real arithmetic written out, not numba's complex type. Every array is C-ordered:
# with any other layout numba indexes through strides, and nothing is vectorised (the
# accumulation took 2.7 times as long).
_F32_1D_IN = nb.types.Array(nb.float32, 1, "C", readonly=True)
_F32_ROWS = nb.types.Array(nb.float32, 2, "C", readonly=True)
_F32_3D_IN = nb.types.Array(nb.float32, 3, "C", readonly=True)
_F32_2D_OUT = nb.types.Array(nb.float32, 2, "C")


def packed_rfft2(image: F32, *, out: F32 | None = None) -> F32:
    """The 2-D DFT of a real float32 image, (rows, cols) float32 in OpenCV's CCS layout.

    Frequency (v, u) of a rows x cols image, u = 0..cols // 2 (the rest are conjugates):
    for 0 < u < cols / 2, row v holds Re and Im at columns 2u - 1 and 2u; the columns
    u = 0 and u = cols / 2 (even cols) are real sequences' spectra packed down their
    column: row 0 holds Re(0), rows 2v - 1 and 2v Re(v) and Im(v) for 0 < v < rows / 2,
    and the last row Re(rows / 2) (even rows). The same numbers as
    ``numpy.fft.rfft2`` (see :func:`unpacked`). ``out`` (float32, the image's shape; it
    may be ``image``) receives the spectrum.
    """
    src = np.ascontiguousarray(image, np.float32)
    return np.asarray(cv2.dft(src) if out is None else cv2.dft(src, out), np.float32)


def packed_irfft2(packed: F32) -> F32:
    """The real image of a CCS spectrum (:func:`packed_rfft2`), scaled as ``irfft2``.

    Transformed in place: ``packed`` holds the image afterwards.
    """
    flags = cv2.DFT_INVERSE | cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE
    return np.asarray(cv2.dft(packed, packed, flags=flags), np.float32)


def unpacked(packed: F32) -> C64:
    """A CCS spectrum as the half spectrum ``numpy.fft.rfft2`` gives, (rows, cols // 2 + 1)."""
    rows, cols = packed.shape
    out = np.empty((rows, cols // 2 + 1), np.complex64)
    _unpack(out.view(np.float32), np.ascontiguousarray(packed, np.float32))
    return out


@nb.njit(inline="always")
def _edge(packed: F32, col: int, v: int) -> tuple[np.float32, np.float32]:
    """(Re, Im) of row ``v`` of the real sequence packed down column ``col``."""
    rows = packed.shape[0]
    if v == 0:
        return packed[0, col], np.float32(0.0)
    if 2 * v < rows:
        return packed[2 * v - 1, col], packed[2 * v, col]
    if 2 * v == rows:
        return packed[rows - 1, col], np.float32(0.0)
    w = rows - v  # the conjugate of a packed row
    return packed[2 * w - 1, col], -packed[2 * w, col]


@nb.njit(inline="always")
def _put_edge(packed: F32, col: int, v: int, re: float, im: float) -> None:
    """Row ``v`` of the real sequence packed down ``col`` (rows past the middle: none)."""
    rows = packed.shape[0]
    if v == 0:
        packed[0, col] = re
    elif 2 * v < rows:
        packed[2 * v - 1, col] = re
        packed[2 * v, col] = im
    elif 2 * v == rows:
        packed[rows - 1, col] = re


@nb.njit(inline="always")
def _unpack_row(packed: F32, v: int, out: F32) -> None:
    """Row ``v`` of a CCS spectrum into ``out`` (re, im interleaved, cols // 2 + 1 pairs)."""
    cols = packed.shape[1]
    row = packed[v]
    for u in range(1, (cols + 1) // 2):  # the pairs of the inner columns
        out[2 * u] = row[2 * u - 1]
        out[2 * u + 1] = row[2 * u]
    out[0], out[1] = _edge(packed, 0, v)
    if cols % 2 == 0:
        out[cols], out[cols + 1] = _edge(packed, cols - 1, v)


@nb.njit(inline="always")
def _pack_row(row: F32, packed: F32, v: int) -> None:
    """``row`` (re, im interleaved, cols // 2 + 1 pairs) as row ``v`` of a CCS spectrum."""
    cols: int = packed.shape[1]
    dst = packed[v]
    for u in range(1, (cols + 1) // 2):
        dst[2 * u - 1] = row[2 * u]
        dst[2 * u] = row[2 * u + 1]
    _put_edge(packed, 0, v, row[0], row[1])
    if cols % 2 == 0:
        _put_edge(packed, cols - 1, v, row[cols], row[cols + 1])


@nb.njit(nb.void(_F32_2D_OUT, _F32_ROWS), cache=True, nogil=True, fastmath=True, boundscheck=False)
def _unpack(out: F32, packed: F32) -> None:
    for v in range(packed.shape[0]):
        _unpack_row(packed, v, out[v])


# one signature per number of frames a call takes (a chunk of at most MAX_FRAMES)
MAX_FRAMES = 4
_ACCUMULATE_SIGNATURES = [
    nb.void(
        nb.types.Array(nb.float32, 3, "C"),  # rhs (A, ny, 2 nxh), updated
        nb.types.UniTuple(_F32_ROWS, n),  # the frames' CCS spectra (ny, nx)
        _F32_ROWS,  # coef (K, 2 A)
        _F32_ROWS,  # row ramps (K, 2 ny)
        _F32_ROWS,  # column ramps (K, 2 nxh)
        nb.int64,  # the band's first row
        nb.int64,  # its rows
    )
    for n in range(1, MAX_FRAMES + 1)
]


@nb.njit(_ACCUMULATE_SIGNATURES, cache=True, nogil=True, fastmath=True, boundscheck=False)
def _accumulate(
    rhs: F32, spectra: tuple[F32, ...], coef: F32, ry: F32, rx: F32, first: int, rows: int
) -> None:
    n_alias, cols = rhs.shape[0], rhs.shape[2] // 2
    sp = np.empty(2 * cols, np.float32)
    tr = np.empty(cols, np.float32)
    ti = np.empty(cols, np.float32)
    for y in range(first, first + rows):
        for k in range(len(spectra)):
            _unpack_row(spectra[k], y, sp)
            rr, ri = ry[k, 2 * y], ry[k, 2 * y + 1]
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


def accumulate(
    rhs: C64,
    spectra: tuple[F32, ...],
    coef: C64,
    ry: C64,
    rx: C64,
    *,
    first: int,
    rows: int,
) -> None:
    """``rhs[a, y, x] += sum_k coef[k, a] ry[k, y] rx[k, x] S_k[y, x]`` for ``rows`` rows y.

    From row ``first`` on, k in order. ``spectra`` are the frames' CCS spectra
    (:func:`packed_rfft2`, C-ordered), S_k their frequencies; ``rhs`` (A, ny, nxh,
    C-ordered) is updated row by row, so that the rows of every alias stay in the cache
    while the (at most :data:`MAX_FRAMES`) frames are added.
    """
    _accumulate(
        rhs.view(np.float32), tuple(spectra), _floats(coef), _floats(ry), _floats(rx), first, rows
    )


def _floats(a: C64) -> F32:
    """A complex64 array as float32 (re, im interleaved along its last axis)."""
    return np.ascontiguousarray(a, np.complex64).view(np.float32)


_PREDICT_SIGNATURE = nb.void(
    _F32_2D_OUT,  # out: CCS (ny, nx)
    _F32_1D_IN,  # coef (2 A,)
    _F32_3D_IN,  # Z (A, ny, 2 nxh)
    _F32_1D_IN,  # row ramp (2 ny,)
    _F32_1D_IN,  # column ramp (2 nxh,)
)


@nb.njit(_PREDICT_SIGNATURE, cache=True, nogil=True, fastmath=True, boundscheck=False)
def _predict(out: F32, coef: F32, Z: F32, ry: F32, rx: F32) -> None:
    n_alias, rows, cols = Z.shape[0], Z.shape[1], Z.shape[2] // 2
    width = out.shape[1]
    o = np.empty(2 * cols, np.float32)
    for y in range(rows):
        for x in range(2 * cols):
            o[x] = 0.0
        for a in range(n_alias):
            cr, ci = coef[2 * a], coef[2 * a + 1]
            z = Z[a, y]
            for x in range(cols):
                o[2 * x] += cr * z[2 * x] - ci * z[2 * x + 1]
                o[2 * x + 1] += cr * z[2 * x + 1] + ci * z[2 * x]
        rr, ri = ry[2 * y], ry[2 * y + 1]
        dst = out[y]
        for x in range(1, (width + 1) // 2):  # the inner columns, straight into place
            pr = rr * rx[2 * x] - ri * rx[2 * x + 1]
            pi = rr * rx[2 * x + 1] + ri * rx[2 * x]
            qr, qi = o[2 * x], o[2 * x + 1]
            dst[2 * x - 1] = qr * pr - qi * pi
            dst[2 * x] = qr * pi + qi * pr
        for x, col in ((0, 0), (width // 2, width - 1)):  # the packed columns
            if x == 0 or width % 2 == 0:
                pr = rr * rx[2 * x] - ri * rx[2 * x + 1]
                pi = rr * rx[2 * x + 1] + ri * rx[2 * x]
                qr, qi = o[2 * x], o[2 * x + 1]
                _put_edge(out, col, y, qr * pr - qi * pi, qr * pi + qi * pr)


def predict(out: F32, coef: C64, Z: C64, ry: C64, rx: C64) -> None:
    """``out = ry[y] rx[x] sum_a coef[a] Z[a, y, x]`` (aliases summed in order), as CCS.

    ``out`` (ny, nx) float32 receives the spectrum in the layout of :func:`packed_rfft2`
    (of frequencies past the middle row, the packed columns keep the conjugate's).
    """
    _predict(out, _floats(coef), Z.view(np.float32), _floats(ry), _floats(rx))


_PLACE_SIGNATURE = nb.void(
    _F32_2D_OUT,  # spec: CCS (Ny, Nx), written
    nb.types.Array(nb.complex64, 2, "C", readonly=True),  # block (ny, nxh)
    nb.types.Array(nb.int64, 1, "C", readonly=True),  # destination row of each block row
    nb.types.Array(nb.int64, 1, "C", readonly=True),  # destination column, -1: none
    nb.boolean,  # conjugate
)


@nb.njit(_PLACE_SIGNATURE, cache=True, nogil=True, fastmath=True, boundscheck=False)
def place(spec: F32, block: C64, iy: I64, ix: I64, conjugate: bool) -> None:
    """``S[iy[i], ix[j]] = block[i, j]`` (conjugated if asked) where ``ix[j] >= 0``.

    S is the HR spectrum ``spec`` holds in the layout of :func:`packed_rfft2`.
    """
    cols = spec.shape[1]
    sign = -1.0 if conjugate else 1.0
    for i in range(block.shape[0]):
        v = iy[i]
        dst = spec[v]
        src = block[i]
        for j in range(block.shape[1]):
            u = ix[j]
            if u < 0:
                continue
            re, im = src[j].real, sign * src[j].imag
            if u == 0:
                _put_edge(spec, 0, v, re, im)
            elif 2 * u == cols:
                _put_edge(spec, cols - 1, v, re, im)
            else:
                dst[2 * u - 1] = re
                dst[2 * u] = im


_F32_2D_IN = nb.types.Array(nb.float32, 2, "C", readonly=True)
_INT2 = nb.types.UniTuple(nb.int64, 2)
_INT4 = nb.types.UniTuple(nb.int64, 4)
_FILL_SIGNATURE = nb.void(
    _F32_2D_OUT,  # out: the padded frame (ny, nx)
    _F32_2D_IN,  # frame (h, w)
    _F32_2D_IN,  # reference (h, w)
    _INT2,  # integer shift (dy, dx) of the frame onto the reference grid
    _INT2,  # pads (top, left)
)


@nb.njit(inline="always")
def _mirror(i: int, n: int) -> int:
    """Index ``i`` reflected into 0..n-1 about the end pixels (``BORDER_REFLECT_101``)."""
    if i < 0:
        return -i
    if i >= n:
        return 2 * (n - 1) - i
    return i


@nb.njit(_FILL_SIGNATURE, cache=True, nogil=True, fastmath=True, boundscheck=False)
def fill_padded(out: F32, frame: F32, reference: F32, shift: tuple[int, int], pads: Any) -> None:
    """``out`` = ``frame`` moved by ``shift`` onto the reference grid, mirror-padded.

    Pixel q of the moved frame is ``frame[q - shift]`` where that is inside the frame,
    else ``reference[q]``; ``out[top + i, left + j]`` is pixel (i, j), and the pads
    around it mirror it about its edge pixels (``cv2.BORDER_REFLECT_101``). Every pad
    must be smaller than the frame.
    """
    h, w = frame.shape
    top, left = pads
    sy, sx = shift
    x0, x1 = min(max(sx, 0), w), max(min(w + sx, w), 0)  # columns the frame covers
    for y in range(out.shape[0]):
        q = _mirror(y - top, h)
        row = out[y]
        ref = reference[q]
        covered = 0 <= q - sy < h and x1 > x0
        for j in range(x0 if covered else w):
            row[left + j] = ref[j]
        if covered:
            src = frame[q - sy]
            for j in range(x0, x1):
                row[left + j] = src[j - sx]
            for j in range(x1, w):
                row[left + j] = ref[j]
        for x in range(left):
            row[x] = row[left + _mirror(x - left, w)]
        for x in range(left + w, out.shape[1]):
            row[x] = row[left + _mirror(x - left, w)]


_PSEUDO_SIGNATURE = nb.int64(
    _F32_2D_OUT,  # prediction in, pseudo-data out (ny, nx)
    _F32_2D_IN,  # frame (h, w)
    _INT2,  # offset: padded pixel (y, x) shows frame pixel (y, x) - offset
    _INT4,  # the padded pixels the frame covers: rows y0:y1, columns x0:x1
    nb.float32,  # clipping level
    nb.int64,  # the sample's step
    nb.types.Array(nb.float32, 1, "C"),  # the sample out
)


@nb.njit(_PSEUDO_SIGNATURE, cache=True, nogil=True, fastmath=True, boundscheck=False)
def pseudo_data(
    pred: F32, frame: F32, offset: Any, valid: Any, clip: np.float32, step: int, sample: F32
) -> int:
    """Huber pseudo-data in place of the prediction, and a sample of the residual's size.

    The frame's pixels are the rectangle ``valid`` = (y0, y1, x0, x1) of the prediction's
    (padded) grid, padded pixel (y, x) showing ``frame[y - oy, x - ox]``. They get
    ``pred + clip(frame - pred, -clip, clip)``; the others keep ``pred``. ``sample``
    receives ``|frame - pred|`` of the frame's pixels on every ``step``-th row and column
    of the grid, in row order (it needs ``ceil(ny / step) * ceil(nx / step)`` places);
    returns how many.
    """
    oy, ox = offset
    y0, y1, x0, x1 = valid
    n = 0
    for y in range(y0, y1):
        p = pred[y]
        f = frame[y - oy]
        if y % step == 0:  # the sample first: it reads the prediction
            for x in range(x0 + (-x0) % step, x1, step):
                sample[n] = abs(f[x - ox] - p[x])
                n += 1
        for x in range(x0, x1):
            p[x] += min(max(f[x - ox] - p[x], -clip), clip)
    return n


_SHIFT_SIGNATURE = nb.types.UniTuple(nb.float64, 5)(
    _F32_2D_IN,  # prediction (ny, nx)
    _F32_2D_IN,  # its derivative along y
    _F32_2D_IN,  # along x
    _F32_2D_IN,  # frame (h, w)
    _INT2,  # offset (as for pseudo_data)
    _INT4,  # the padded pixels the frame covers
    nb.float64,  # residuals beyond this do not vote
)


@nb.njit(_SHIFT_SIGNATURE, cache=True, nogil=True, fastmath=True, boundscheck=False)
def shift_normal_equations(
    pred: F32, dy: F32, dx: F32, frame: F32, offset: Any, valid: Any, limit: float
) -> tuple[float, float, float, float, float]:
    """Sums of the Gauss-Newton step that moves the prediction onto the frame.

    Over the frame's pixels (``offset`` and ``valid`` as for :func:`pseudo_data`) whose
    residual ``r = frame - pred`` is at most ``limit`` in size: ``sum dy^2``,
    ``sum dy dx``, ``sum dx^2``, ``sum dy r`` and ``sum dx r`` (float64 sums of the
    float32 values).
    """
    oy, ox = offset
    y0, y1, x0, x1 = valid
    a11 = a12 = a22 = b1 = b2 = 0.0
    for y in range(y0, y1):
        f, p, gy, gx = frame[y - oy], pred[y], dy[y], dx[y]
        for x in range(x0, x1):
            r = f[x - ox] - p[x]
            if abs(r) <= limit:
                vy, vx, rr = np.float64(gy[x]), np.float64(gx[x]), np.float64(r)
                a11 += vy * vy
                a12 += vy * vx
                a22 += vx * vx
                b1 += vy * rr
                b2 += vx * rr
    return a11, a12, a22, b1, b2


@nb.njit(
    nb.float64(_F32_2D_IN, _F32_2D_IN, _INT4),
    cache=True,
    nogil=True,
    fastmath=True,
    boundscheck=False,
)
def squared_residual(target: F32, pred: F32, rect: Any) -> float:
    """``sum (target - pred)^2`` over rows y0:y1 and columns x0:x1 (a float64 sum)."""
    y0, y1, x0, x1 = rect
    total = 0.0
    for y in range(y0, y1):
        t, p = target[y], pred[y]
        for x in range(x0, x1):
            r = np.float64(t[x] - p[x])
            total += r * r
    return total
