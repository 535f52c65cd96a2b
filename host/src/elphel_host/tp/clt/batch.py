"""The production CLT: every colour of one camera's shifted tiles, batched, on the kept frequencies.

This is what the tile processor runs. It is the reference lattice transform
(:mod:`elphel_host.tp.clt.reference`) reorganised for speed and computes the same numbers
(``tests/host/tp/test_clt_batch.py`` checks it against that and against the tile-by-tile
definition):

* Only the frequencies that survive the colour filters are computed (red and blue: the
  4x4 lowest, below their lattice's alias band; green: ``kh + kv <= green_band``; mono:
  all 64). The box of red/blue frequencies comes first in the frequency list, so red and
  blue are a prefix of green.
* The mosaic is regrouped once per image by Bayer cell (:func:`image_cells`: per cell
  its four pixels side by side, in colour order), so a tile's samples are a few
  contiguous runs. The footprint is cell-aligned: 9x9 cells per tile (a tile starting
  on an odd pixel starts one pixel into its first cell), of which each plane has 8x8
  samples inside the tile; which 8x8 depends on the tile's start parity, so tiles are
  grouped by parity and each group and colour has its own matrix. The basis is a pure
  exponential in the sample index (``E[k, j+1] = E[k, j] exp(i OMEGA[k])``), so the
  one-pixel offset of an odd start is a phase rotation, folded into the rotation by the
  fractional shift. The matrices also
  hold the colour weight and colour LPF (as square roots, so a pair product carries them
  once) and, for green, the sum of the two green lattices.
* The shifted window is ``w_s(j) = cos(pi s/16) w0(j) + sin(pi s/16) w1(j)`` along each
  axis (one pair of fixed windows per start parity, zero outside the tile), so the
  gather and the window are one fused pass (:func:`elphel_host.tp.fused.gather_windowed`)
  that writes the rows the colour products read.
* What is left per tile is one phase rotation by the camera's fractional shift and start
  parity, common to all colours: :func:`camera_spectra` applies it, the tile processor
  folds it into its pair products (:func:`raw_spectra` returns the shifts).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from elphel_host.tp.bayer import Lattice, lattices
from elphel_host.tp.clt.transform import E_COMPLEX, OMEGA, TILE
from elphel_host.tp.geometry import TilePlacement

F32 = NDArray[np.float32]
C64 = NDArray[np.complex64]


@dataclass(frozen=True)
class FrequencySet:
    """Frequencies kept: ``kh[f], kv[f]``; the first ``n_box`` are shared by all colours."""

    kh: NDArray[np.intp]
    kv: NDArray[np.intp]
    n_box: int

    @property
    def size(self) -> int:
        return int(self.kh.size)


def frequency_set(bayer: str | None, *, green_band: int, box: int = 4) -> FrequencySet:
    """Frequencies of a sensor: box (red/blue) first, then the rest of green's band."""
    k = np.arange(8)
    kh, kv = (a.ravel() for a in np.meshgrid(k, k, indexing="ij"))
    if bayer is None:
        return FrequencySet(kh=kh, kv=kv, n_box=64)
    in_box = (kh < box) & (kv < box)
    rest = ~in_box & (kh + kv <= green_band)
    order = np.concatenate([np.nonzero(in_box)[0], np.nonzero(rest)[0]])
    return FrequencySet(kh=kh[order], kv=kv[order], n_box=int(in_box.sum()))


@dataclass(frozen=True)
class CameraTransform:
    """Everything fixed about turning one camera's mosaic into colour spectra."""

    fset: FrequencySet
    colour_sizes: tuple[int, ...]  # frequencies per colour (R, B, G) or (mono,)
    cell: int  # 2 (Bayer cell) or 1 (mono)
    span: int  # footprint samples per plane along an axis: 9 (Bayer) or 16 (mono)
    inner: int  # of which inside the tile: 8 (Bayer) or 16 (mono)
    plane_rows: NDArray[np.intp]  # (planes,) row parity of each plane, colour order
    plane_cols: NDArray[np.intp]  # (planes,) column parity of each plane
    first_y: NDArray[np.int64]  # (parities, planes) first footprint row inside the tile
    first_x: NDArray[np.int64]  # (parities, planes) first footprint column inside the tile
    # per colour: its planes, and per start parity (2 py + px) its matrix
    # (planes * inner^2, 2*2*F_c) from the samples inside the tile
    blocks: tuple[tuple[slice, F32], ...]
    rows_w: F32  # (parities, planes, 2, span): sine and cosine window down the columns
    cols_w: F32  # (parities, planes, 2, span): along the rows
    angles: F32  # (2, 2F): rotation angle per (shift_x, shift_y) for (which, f)
    pad: int


def _extended_basis(length: int) -> NDArray[np.complex128]:
    """``E_COMPLEX`` continued past the tile: ``E[k, j] = E[k, 0] exp(i OMEGA[k] j)``."""
    j = np.arange(length)
    out: NDArray[np.complex128] = E_COMPLEX[:, :1] * np.exp(1j * OMEGA[:, None] * j[None, :])
    return out


def _plane_matrix(lat: Lattice, span: int, fset: FrequencySet, nf: int) -> NDArray[np.float64]:
    """Plane samples (v, u) at cell positions ``step * v + row`` -> (which, re/im, f)."""
    e = _extended_basis(lat.step * span)
    ys = lat.step * np.arange(span) + lat.row
    xs = lat.step * np.arange(span) + lat.col
    ev = e[fset.kv[:nf]][:, ys]  # (F, v)
    eh = e[fset.kh[:nf]][:, xs]  # (F, u)
    z2 = ev[:, :, None] * eh[:, None, :]  # (F, v, u)
    z1 = np.conj(ev)[:, :, None] * eh[:, None, :]
    coef = np.stack([z2, z1]).reshape(2, nf, span * span)  # (which, f, samples)
    out = np.stack([coef.real, coef.imag], axis=1)  # (which, re/im, f, samples)
    return out.transpose(3, 0, 1, 2).reshape(span * span, 2 * 2 * nf) * lat.scale


def camera_transform(
    bayer: str | None,
    colour_weights: NDArray[np.floating],
    *,
    green_band: int,
    pad: int,
) -> CameraTransform:
    """Prepare the transform matrices of a sensor.

    Parameters
    ----------
    bayer
        Pattern or None.
    colour_weights
        ``(colours, 8, 2, 8)`` weights (colour weight x colour LPF, [kh, which, kv]).
    green_band
        Green (and mono: ignored) frequency band, ``kh + kv <= green_band``.
    pad
        Even padding of the mosaic, pixels.
    """
    if pad % 2:
        raise ValueError(f"pad={pad}; allowed: even (keeps the Bayer parity)")
    fset = frequency_set(bayer, green_band=green_band)
    lats = lattices(bayer)
    ncol = 1 if bayer is None else 3
    sizes = tuple(fset.size if (bayer is None or c == 2) else fset.n_box for c in range(ncol))
    cell = 1 if bayer is None else 2
    # a tile starts on either parity; its cell-aligned footprint is one sample wider
    span = TILE if bayer is None else TILE // 2 + 1
    rows, cols, full = _colour_blocks(lats, colour_weights, fset, sizes, span)
    f = fset.size
    angles = np.zeros((2, 2 * f))
    angles[0] = np.tile(OMEGA[fset.kh], 2)
    angles[1] = np.concatenate([OMEGA[fset.kv], -OMEGA[fset.kv]])
    plane_rows = np.array(rows, dtype=np.intp)
    plane_cols = np.array(cols, dtype=np.intp)
    first_y, first_x = _first_inside(cell, plane_rows), _first_inside(cell, plane_cols)
    inner = TILE // cell
    blocks = [
        (planes, _parity_matrices(m, planes, span, inner, first_y, first_x)) for planes, m in full
    ]
    return CameraTransform(
        fset=fset,
        colour_sizes=sizes,
        cell=cell,
        span=span,
        inner=inner,
        plane_rows=plane_rows,
        plane_cols=plane_cols,
        first_y=first_y,
        first_x=first_x,
        blocks=tuple(blocks),
        rows_w=_window_factors(cell, span, plane_rows),
        cols_w=_window_factors(cell, span, plane_cols),
        angles=angles.astype(np.float32),
        pad=pad,
    )


def _first_inside(cell: int, offsets: NDArray[np.intp]) -> NDArray[np.int64]:
    """``(parities, planes)``: the first footprint sample inside the tile along an axis.

    Sample j of a plane with cell offset o lies at tile-local ``cell j + o - parity``.
    """
    parity = np.arange(cell)[:, None]
    out: NDArray[np.int64] = np.maximum(0, -((offsets[None, :] - parity) // cell)).astype(np.int64)
    return out


def _parity_matrices(
    m: F32,
    planes: slice,
    span: int,
    inner: int,
    first_y: NDArray[np.int64],
    first_x: NDArray[np.int64],
) -> F32:
    """A colour's footprint matrix restricted, per start parity, to the samples inside the tile.

    Returns ``(parities, planes * inner^2, columns)``, parity ``py * cell + px``.
    """
    cell = first_y.shape[0]
    out = []
    for py in range(cell):
        for px in range(cell):
            rows = [
                k * span * span + (first_y[py, p] + v) * span + first_x[px, p] + u
                for k, p in enumerate(range(planes.start, planes.stop))
                for v in range(inner)
                for u in range(inner)
            ]
            out.append(m[rows])
    return np.stack(out)


def _colour_blocks(
    lats: Sequence[Lattice],
    colour_weights: NDArray[np.floating],
    fset: FrequencySet,
    sizes: tuple[int, ...],
    span: int,
) -> tuple[list[int], list[int], list[tuple[slice, F32]]]:
    """Per colour, its planes' (row, col) in the cell and its weighted footprint matrix."""
    rows: list[int] = []
    cols: list[int] = []
    blocks: list[tuple[slice, F32]] = []
    for colour, size in enumerate(sizes):
        members = [lat for lat in lats if lat.colour == colour]
        first = len(rows)
        mats = []
        for lat in members:
            rows.append(lat.row)
            cols.append(lat.col)
            mats.append(_plane_matrix(lat, span, fset, size))
        m = np.concatenate(mats, axis=0)
        # fold in the square root of the colour weight: the pair product then carries it once
        wgt = colour_weights[colour][fset.kh[:size], :, fset.kv[:size]]  # (F, which)
        root = np.sqrt(np.maximum(wgt.T, 0.0))  # (which, F)
        m = m * np.repeat(root, 2, axis=0).ravel()[None, :]  # columns (which, re/im, f)
        blocks.append((slice(first, len(rows)), m.astype(np.float32)))
    return rows, cols, blocks


def image_cells(image: NDArray[np.floating], tr: CameraTransform) -> F32:
    """One camera's image, padded by ``tr.pad`` pixels, by cell: ``(rows/c, cols/c, planes)``.

    Plane p of cell (i, j) is the padded pixel ``(c i + plane_rows[p], c j + plane_cols[p])``
    (c = 1 mono, 2 Bayer; planes in colour order), so one tile's samples of every colour
    are a few contiguous runs (:func:`elphel_host.tp.fused.gather_windowed` reads them).
    Out-of-image samples repeat the border pixel of the same Bayer parity (reference 1):
    in cells, that is the border cell repeated.
    """
    img = np.asarray(image, dtype=np.float32)
    c, pc = tr.cell, tr.pad // tr.cell
    if img.ndim != 2 or img.shape[0] % c or img.shape[1] % c:
        raise ValueError(f"image {img.shape}; allowed: 2-D, sides multiples of {c}")
    h, w = img.shape[0] // c, img.shape[1] // c
    grid = img.reshape(h, c, w, c)
    out = np.empty((h + 2 * pc, w + 2 * pc, tr.plane_rows.size), dtype=np.float32)
    inner = out[pc : pc + h, pc : pc + w]
    for p, (r, q) in enumerate(zip(tr.plane_rows, tr.plane_cols, strict=True)):
        inner[:, :, p] = grid[:, r, :, q]
    out[:pc] = out[pc]
    out[pc + h :] = out[pc + h - 1]
    out[:, :pc] = out[:, pc : pc + 1]
    out[:, pc + w :] = out[:, pc + w - 1 : pc + w]
    return out


def _window_factors(cell: int, span: int, offsets: NDArray[np.intp]) -> F32:
    """Per start parity, plane and window, the window on the planes' samples along an axis.

    ``out[parity, plane, a, j]`` is the sine window (a = 0) or the cosine one (a = 1) at
    the footprint's sample j of the plane whose cell offset along the axis is
    ``offsets[plane]``, for a tile starting on ``parity``; zero on the samples outside
    the 16-sample tile. The window of a tile shifted by s is ``cos(pi s/16) w0 +
    sin(pi s/16) w1`` along each axis, and the 2-D window is the product of the two axes'.
    """
    out = np.zeros((cell, offsets.size, 2, span))
    for parity in range(cell):
        j = cell * np.arange(span)[None, :] + offsets[:, None] - parity  # tile-local sample
        inside = (j >= 0) & (j < TILE)
        for a in range(2):
            out[parity, :, a] = np.where(
                inside, np.sin(np.pi * (j + 0.5) / TILE + a * np.pi / 2), 0
            )
    return out.astype(np.float32)


def camera_spectra(
    cells: F32,
    tr: CameraTransform,
    at: TilePlacement,
    *,
    kernels: list[C64] | None = None,
    kernel_index: NDArray[np.intp] | None = None,
) -> list[C64]:
    """Colour spectra of one camera's tiles: per colour ``(T, 2, F_c)`` complex64.

    :func:`raw_spectra` followed by the phase rotation by each tile's shift.
    With ``kernels`` (per colour ``(n_kernels, 2, F)`` from
    :func:`elphel_host.tp.kernels.kernel_spectra`) each tile is multiplied by the kernel
    ``kernel_index[t]`` (aberration correction), before the phase rotation as in the
    reference.

    Parameters
    ----------
    cells
        :func:`image_cells` of the camera (prepare it once per image).
    tr
        :func:`camera_transform` of the sensor.
    at
        Where the camera's tiles lie on the sensor.
    """
    t = at.left_x.shape[0]
    packed = np.empty((t, spectrum_floats(tr)), dtype=np.float32)
    shifts, rows = raw_spectra(cells, tr, at, packed, kernels=kernels, kernel_index=kernel_index)
    phase = _rotations(shifts, tr)
    return [
        (v[rows, :, 0] + 1j * v[rows, :, 1]).astype(np.complex64) * phase[:, :, : v.shape[3]]
        for v in colour_views(packed, tr)
    ]


def spectrum_floats(tr: CameraTransform) -> int:
    """Floats per tile of :func:`raw_spectra`'s packed colour spectra: ``4 sum(F_c)``."""
    return 4 * sum(tr.colour_sizes)


def colour_views(packed: F32, tr: CameraTransform) -> list[F32]:
    """Per colour, a ``(T, 2, 2, F_c)`` (which, re/im, f) view of packed spectra."""
    t = packed.shape[0]
    out = []
    start = 0
    for n in tr.colour_sizes:
        out.append(packed[:, start : start + 4 * n].reshape(t, 2, 2, n))
        start += 4 * n
    return out


def raw_spectra(
    cells: F32,
    tr: CameraTransform,
    at: TilePlacement,
    out: F32,
    *,
    kernels: list[C64] | None = None,
    kernel_index: NDArray[np.intp] | None = None,
) -> tuple[F32, NDArray[np.int64]]:
    """One camera's colour spectra before the phase rotation, into ``out``; the rotation.

    Each tile's samples inside the tile are gathered and windowed in one pass
    (:func:`elphel_host.tp.fused.gather_windowed`) into rows grouped by the tile's start
    parity, then transformed by one matrix product per parity and colour. ``kernels`` and
    ``kernel_index`` as in :func:`camera_spectra`.

    Parameters
    ----------
    cells, tr, at
        As in :func:`camera_spectra`.
    out
        ``(T, spectrum_floats(tr))`` float32, filled with the colours one after the
        other, each ``(which, re/im, f)`` (the layout of :func:`colour_views`).

    Returns
    -------
    shifts, rows
        ``(T, 2)`` float32: the shift (x, y) each tile's spectra still need to be rotated
        by (the fractional shift less the start parity); ``(T,)``: the row of ``out``
        that holds tile t.
    """
    t = at.left_x.shape[0]
    samples, par_x, par_y, order = _windowed_samples(cells, tr, at)
    n_plane = tr.inner * tr.inner
    bounds = np.searchsorted((par_y * tr.cell + par_x)[order], np.arange(tr.cell * tr.cell + 1))
    for g in range(tr.cell * tr.cell):
        lo, hi = int(bounds[g]), int(bounds[g + 1])
        start = 0
        for (planes, mats), n in zip(tr.blocks, tr.colour_sizes, strict=True):
            part = samples[lo:hi, planes.start * n_plane : planes.stop * n_plane]
            np.matmul(part, mats[g], out=out[lo:hi, start : start + 4 * n])
            start += 4 * n
    if kernels is not None and kernel_index is not None:
        for colour, n in enumerate(tr.colour_sizes):
            kern = kernels[colour][kernel_index[order]][:, :, :n]
            _convolve(colour_views(out, tr)[colour], kern)
    shifts = np.empty((t, 2), dtype=np.float32)
    shifts[:, 0] = at.shift_x - par_x
    shifts[:, 1] = at.shift_y - par_y
    dest = np.empty(t, dtype=np.int64)
    dest[order] = np.arange(t)
    return shifts, dest


def _windowed_samples(
    cells: F32, tr: CameraTransform, at: TilePlacement
) -> tuple[F32, NDArray[np.int64], NDArray[np.int64], NDArray[np.intp]]:
    """Each tile's windowed samples inside the tile, rows grouped by start parity.

    Returns the samples ``(T, planes * inner^2)``, each tile's start parity along x and
    y, and ``order``: row i holds tile ``order[i]`` (parity groups in order 2 py + px).
    """
    # the compiled kernels load on first use: commands that never run a pass skip numba
    from elphel_host.tp.fused import gather_windowed

    c, span = tr.cell, tr.span
    # cell-aligned footprint: an odd start is one cell earlier, its samples at 1..16
    par_x = np.ascontiguousarray(at.left_x & (c - 1), dtype=np.int64)
    par_y = np.ascontiguousarray(at.top_y & (c - 1), dtype=np.int64)
    cols = np.clip((at.left_x + tr.pad - par_x) // c, 0, cells.shape[1] - span).astype(np.int64)
    rows = np.clip((at.top_y + tr.pad - par_y) // c, 0, cells.shape[0] - span).astype(np.int64)
    order = np.argsort(par_y * c + par_x, kind="stable")
    dest = np.empty(order.size, dtype=np.int64)
    dest[order] = np.arange(order.size)
    samples = np.empty((order.size, tr.plane_rows.size * tr.inner**2), dtype=np.float32)
    gather_windowed(
        cells,
        rows,
        cols,
        par_y,
        par_x,
        _window_trig(at.shift_y),
        _window_trig(at.shift_x),
        tr.rows_w,
        tr.cols_w,
        tr.first_y,
        tr.first_x,
        dest,
        samples,
    )
    return samples, par_x, par_y, order


def _convolve(planar: F32, kernel: C64) -> None:
    """Multiply planar spectra ``(T, 2, 2, F)`` (which, re/im, f) by complex ``(T, 2, F)``."""
    re, im = planar[:, :, 0].copy(), planar[:, :, 1]
    planar[:, :, 0] = re * kernel.real - im * kernel.imag
    planar[:, :, 1] = re * kernel.imag + im * kernel.real


def _window_trig(shift: NDArray[np.floating]) -> F32:
    """``(T, 2)``: cos and sin of ``pi s / 16``, the weights of the two fixed windows."""
    a = np.pi / TILE * np.asarray(shift, dtype=np.float64)
    out: F32 = np.stack([np.cos(a), np.sin(a)], axis=1).astype(np.float32)
    return out


def _rotations(shifts: F32, tr: CameraTransform) -> C64:
    """Phase rotations by ``(x, y)`` shifts: ``(T or 1, 2, F)`` complex64."""
    ang = shifts @ tr.angles  # (T or 1, 2F)
    phase = np.empty(ang.shape, dtype=np.complex64)
    phase.real = np.cos(ang)
    phase.imag = np.sin(ang)
    return phase.reshape(-1, 2, tr.fset.size)


def expand(products: C64, fset: FrequencySet) -> C64:
    """Compact products ``(..., 2, F)`` -> full layout ``(..., 8, 2, 8)`` (zeros elsewhere)."""
    out = np.zeros((*products.shape[:-2], 8, 2, 8), dtype=np.complex64)
    out[..., fset.kh, 0, fset.kv] = products[..., 0, :]
    out[..., fset.kh, 1, fset.kv] = products[..., 1, :]
    return out
