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
  its four pixels side by side, in colour order), so a batch of tiles is gathered by one
  strided indexing operation. The gathered footprint is cell-aligned: 9x9 cells per tile
  (a tile starting on an odd pixel starts one pixel into its first cell), so every tile
  has the same colour layout and every colour fixed transform matrices, whatever the
  parity of the tile's origin. The basis is a pure exponential in the sample index
  (``E[k, j+1] = E[k, j] exp(i OMEGA[k])``), so the one-pixel offset of an odd start is a
  phase rotation, folded into the rotation by the fractional shift. The matrices also
  hold the colour weight and colour LPF (as square roots, so a pair product carries them
  once) and, for green, the sum of the two green lattices.
* The shifted window is ``w_s(j) = cos(pi s/16) w0(j) + sin(pi s/16) w1(j)``, so the 2-D
  window of every tile is a 4-term combination of fixed windows (one set per start
  parity, zero outside the tile): one small matrix product.
* What is left per tile is one phase rotation by the camera's fractional shift and start
  parity, common to all colours.
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
    span: int  # samples per plane along an axis: 9 (Bayer) or 16 (mono)
    plane_rows: NDArray[np.intp]  # (planes,) row parity of each plane, colour order
    plane_cols: NDArray[np.intp]  # (planes,) column parity of each plane
    blocks: tuple[tuple[slice, F32], ...]  # per colour: planes, matrix (n, 2*2*F_c)
    windows: F32  # (parities * 4, planes * span^2): fixed windows per start parity
    angles: F32  # (2, 2F): rotation angle per (shift_x, shift_y) for (which, f)
    pad: int


def _extended_basis(length: int) -> NDArray[np.complex128]:
    """``E_COMPLEX`` continued past the tile: ``E[k, j] = E[k, 0] exp(i OMEGA[k] j)``."""
    j = np.arange(length)
    out: NDArray[np.complex128] = E_COMPLEX[:, :1] * np.exp(1j * OMEGA[:, None] * j[None, :])
    return out


def _plane_matrix(lat: Lattice, span: int, fset: FrequencySet, nf: int) -> NDArray[np.float64]:
    """Plane samples (v, u) at cell positions ``step * v + row`` -> (which, f, re/im)."""
    e = _extended_basis(lat.step * span)
    ys = lat.step * np.arange(span) + lat.row
    xs = lat.step * np.arange(span) + lat.col
    ev = e[fset.kv[:nf]][:, ys]  # (F, v)
    eh = e[fset.kh[:nf]][:, xs]  # (F, u)
    z2 = ev[:, :, None] * eh[:, None, :]  # (F, v, u)
    z1 = np.conj(ev)[:, :, None] * eh[:, None, :]
    coef = np.stack([z2, z1]).reshape(2, nf, span * span)  # (which, f, samples)
    out = np.stack([coef.real, coef.imag], axis=-1)  # (which, f, samples, re/im)
    return out.transpose(2, 0, 1, 3).reshape(span * span, 2 * nf * 2) * lat.scale


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
    rows, cols, blocks = _colour_blocks(lats, colour_weights, fset, sizes, span)
    f = fset.size
    angles = np.zeros((2, 2 * f))
    angles[0] = np.tile(OMEGA[fset.kh], 2)
    angles[1] = np.concatenate([OMEGA[fset.kv], -OMEGA[fset.kv]])
    plane_rows = np.array(rows, dtype=np.intp)
    plane_cols = np.array(cols, dtype=np.intp)
    return CameraTransform(
        fset=fset,
        colour_sizes=sizes,
        cell=cell,
        span=span,
        plane_rows=plane_rows,
        plane_cols=plane_cols,
        blocks=tuple(blocks),
        windows=_window_tables(cell, span, plane_rows, plane_cols).astype(np.float32),
        angles=angles.astype(np.float32),
        pad=pad,
    )


def _colour_blocks(
    lats: Sequence[Lattice],
    colour_weights: NDArray[np.floating],
    fset: FrequencySet,
    sizes: tuple[int, ...],
    span: int,
) -> tuple[list[int], list[int], list[tuple[slice, F32]]]:
    """Per colour, its planes' (row, col) in the cell and its weighted transform matrix."""
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
        m = m * np.repeat(root.ravel(), 2)[None, :]
        blocks.append((slice(first, len(rows)), m.astype(np.float32)))
    return rows, cols, blocks


def image_cells(image: NDArray[np.floating], tr: CameraTransform) -> F32:
    """One camera's image, padded by ``tr.pad`` pixels, by cell: ``(rows/c, cols/c, planes)``.

    Plane p of cell (i, j) is the padded pixel ``(c i + plane_rows[p], c j + plane_cols[p])``
    (c = 1 mono, 2 Bayer; planes in colour order), so one tile's samples of every colour
    are a few contiguous runs and a batch of tiles is gathered by one indexing operation.
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


def _window_tables(
    cell: int, span: int, rows: NDArray[np.intp], cols: NDArray[np.intp]
) -> NDArray[np.float64]:
    """Fixed windows ``w_a(y) w_b(x)`` on the planes' samples, per tile start parity.

    Row ``parity * 4 + a * 2 + b`` (parity = 2 (top & 1) + (left & 1); a, b: 0 = the sine
    window, 1 = the cosine one) is the window of the cell-aligned footprint, zero on the
    samples outside the 16x16 tile. The window of a tile shifted by s is
    ``cos(pi s/16) w0 + sin(pi s/16) w1`` along each axis.
    """
    out = []
    for parity in range(cell * cell):
        py, px = divmod(parity, cell) if cell == 2 else (0, 0)
        j = cell * np.arange(span)
        jy = j[None, :] + rows[:, None] - py  # (planes, v): tile-local row
        jx = j[None, :] + cols[:, None] - px
        inside_y = (jy >= 0) & (jy < TILE)
        inside_x = (jx >= 0) & (jx < TILE)
        for a in range(2):
            wy = np.where(inside_y, np.sin(np.pi * (jy + 0.5) / TILE + a * np.pi / 2), 0.0)
            for b in range(2):
                wx = np.where(inside_x, np.sin(np.pi * (jx + 0.5) / TILE + b * np.pi / 2), 0.0)
                out.append((wy[:, :, None] * wx[:, None, :]).ravel())
    return np.array(out)


def camera_spectra(
    cells: F32,
    tr: CameraTransform,
    at: TilePlacement,
    *,
    kernels: list[C64] | None = None,
    kernel_index: NDArray[np.intp] | None = None,
) -> list[C64]:
    """Colour spectra of one camera's tiles: per colour ``(T, 2, F_c)`` complex64.

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
    c, span = tr.cell, tr.span
    left_x, shift_x, top_y, shift_y = at.left_x, at.shift_x, at.top_y, at.shift_y
    t = left_x.shape[0]
    # cell-aligned footprint: an odd start is one cell earlier, its samples at 1..16
    par_x = left_x & (c - 1)
    par_y = top_y & (c - 1)
    cols = np.clip((left_x + tr.pad - par_x) // c, 0, cells.shape[1] - span)
    rows = np.clip((top_y + tr.pad - par_y) // c, 0, cells.shape[0] - span)
    samples = _gather_tiles(cells, span, rows, cols)  # (T, planes * v * u)
    n_plane = span * span
    coef = _window_coefficients(at.shift_y, at.shift_x)
    parity = par_y * c + par_x
    # one rotation by the fractional shift (and the cell offset), shared by all colours
    uniform = bool(np.ptp(shift_x) == 0 and np.ptp(shift_y) == 0 and np.ptp(parity) == 0)
    one = slice(0, 1) if uniform else slice(None)  # e.g. a first pass: one shift for all
    shifts = np.stack([shift_x[one] - par_x[one], shift_y[one] - par_y[one]], axis=1)
    phase3 = _rotations(shifts.astype(np.float32), tr)
    if uniform:
        # the one window and the one rotation go into the matrices: no pass over the tiles
        mats = _uniform_matrices(tr, coef[:1], int(parity[0]), phase3[0])
    else:
        spread = np.zeros((t, tr.windows.shape[0]), dtype=np.float32)
        np.put_along_axis(spread, parity[:, None] * 4 + np.arange(4), coef, axis=1)
        samples *= spread @ tr.windows
        mats = [mat for _, mat in tr.blocks]
    result = []
    for colour, ((planes, _), mat, n) in enumerate(
        zip(tr.blocks, mats, tr.colour_sizes, strict=True)
    ):
        part = samples[:, planes.start * n_plane : planes.stop * n_plane]
        z = (part @ mat).view(np.complex64).reshape(t, 2, n)
        if kernels is not None and kernel_index is not None:
            z *= kernels[colour][kernel_index][:, :, :n]
        if not uniform:
            z *= phase3[:, :, :n]
        result.append(z)
    return result


def _uniform_matrices(tr: CameraTransform, coef: F32, parity: int, phase: C64) -> list[F32]:
    """The colour matrices with one window (``coef`` (1, 4) at ``parity``) and one rotation."""
    n_plane = tr.span * tr.span
    window = (coef @ tr.windows[parity * 4 : parity * 4 + 4])[0]
    mats = []
    for (planes, mat), n in zip(tr.blocks, tr.colour_sizes, strict=True):
        m = mat * window[planes.start * n_plane : planes.stop * n_plane, None]
        m.view(np.complex64)[...] *= phase[:, :n].reshape(1, 2 * n)
        mats.append(m)
    return mats


def _gather_tiles(cells: F32, span: int, rows: NDArray[np.intp], cols: NDArray[np.intp]) -> F32:
    """Each tile's ``span x span`` footprint of every plane: ``(T, planes * span * span)``."""
    s0, s1, s2 = cells.strides
    npl = cells.shape[2]
    # planes first in the view, so the gathered copy is already plane-major (no transpose)
    view = np.lib.stride_tricks.as_strided(
        cells,
        shape=(cells.shape[0] - span + 1, cells.shape[1] - span + 1, npl, span, span),
        strides=(s0, s1, s2, s0, s1),
        writeable=False,
    )
    out: F32 = view[rows, cols].reshape(rows.shape[0], npl * span * span)
    return out


def _window_coefficients(shift_y: NDArray[np.floating], shift_x: NDArray[np.floating]) -> F32:
    """Weights of the 4 fixed windows (per start parity) that make each tile's shifted window."""
    a = np.pi / TILE
    cy, sy = np.cos(a * shift_y), np.sin(a * shift_y)
    cx, sx = np.cos(a * shift_x), np.sin(a * shift_x)
    return np.stack([cy * cx, cy * sx, sy * cx, sy * sx], axis=1).astype(np.float32)


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
