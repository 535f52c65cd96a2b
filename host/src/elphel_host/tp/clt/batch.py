"""The production CLT: every colour of one camera's shifted tiles, batched, on the kept frequencies.

This is what the tile processor runs. It is the reference lattice transform
(:mod:`elphel_host.tp.clt.reference`) reorganised for speed and computes the same numbers
(``tests/host/tp/test_clt_batch.py`` checks it against that and against the tile-by-tile
definition):

* Only the frequencies that survive the colour filters are computed (red and blue: the
  4x4 lowest, below their lattice's alias band; green: ``kh + kv <= green_band``; mono:
  all 64). The box of red/blue frequencies comes first in the frequency list, so red and
  blue are a prefix of green.
* Each tile's samples are read from the mosaic by Bayer cell (a plane is one pixel of
  each 2x2 cell; mono: one plane of single pixels). The footprint is cell-aligned: 9x9
  cells per tile (a tile starting on an odd pixel starts one pixel into its first cell),
  of which each plane has 8x8 samples inside the tile; which 8x8 depends on the tile's
  start parity, so each table has one entry per parity. Outside the image a plane's
  samples repeat its border pixel (reference 1). The basis is a pure exponential in the sample index
  (``E[k, j+1] = E[k, j] exp(i OMEGA[k])``), so the one-pixel offset of an odd start is a
  phase rotation, folded into the rotation by the fractional shift.
* The shifted window is ``w_s(j) = cos(pi s/16) w0(j) + sin(pi s/16) w1(j)`` along each
  axis (one pair of fixed windows per start parity, zero outside the tile).
* The 2-D basis is the product of a basis along x and one along y, so each plane is
  transformed along its rows, then down its columns (about a quarter of the
  multiply-adds of one dense product per colour), in one compiled pass per tile that
  also gathers and windows the samples (:func:`elphel_host.tp.fused.tile_spectra`).
  Green's two planes are summed in the column pass; the colour weight and colour LPF
  (as square roots, so a pair product carries them once) are applied on the way out.
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
    window_y: F32  # (parities, planes, 2, inner): sine and cosine window down the columns
    window_x: F32  # (parities, planes, 2, inner): along the rows
    row_basis: F32  # (parities, planes, inner, 16): (re | im) of the basis along x, kh 0..7
    col_basis: F32  # (parities, planes, 2, 8, inner): re, im of the basis along y, kv 0..7
    colours: NDArray[np.int64]  # (colours, 4): first plane, end plane, frequencies, kv count
    positions: NDArray[np.uint64]  # (F,): 16 kv + kh, where frequency f is in a column sum
    roots: F32  # (colours, 2, F): square root of the colour weight (x LPF) per (which, f)
    angles: F32  # (2, 2F): rotation angle per (shift_x, shift_y) for (which, f)
    pad: int


def _extended_basis(length: int) -> NDArray[np.complex128]:
    """``E_COMPLEX`` continued past the tile: ``E[k, j] = E[k, 0] exp(i OMEGA[k] j)``."""
    j = np.arange(length)
    out: NDArray[np.complex128] = E_COMPLEX[:, :1] * np.exp(1j * OMEGA[:, None] * j[None, :])
    return out


def camera_transform(
    bayer: str | None,
    colour_weights: NDArray[np.floating],
    *,
    green_band: int,
    pad: int,
) -> CameraTransform:
    """Prepare the transform tables of a sensor.

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
    ncol = 1 if bayer is None else 3
    planes = sorted(lattices(bayer), key=lambda lat: lat.colour)  # stable: colour order
    sizes = tuple(fset.size if (bayer is None or c == 2) else fset.n_box for c in range(ncol))
    cell = 1 if bayer is None else 2
    # a tile starts on either parity; its cell-aligned footprint is one sample wider
    span = TILE if bayer is None else TILE // 2 + 1
    inner = TILE // cell
    f = fset.size
    angles = np.zeros((2, 2 * f))
    angles[0] = np.tile(OMEGA[fset.kh], 2)
    angles[1] = np.concatenate([OMEGA[fset.kv], -OMEGA[fset.kv]])
    plane_rows = np.array([lat.row for lat in planes], dtype=np.intp)
    plane_cols = np.array([lat.col for lat in planes], dtype=np.intp)
    first_y, first_x = _first_inside(cell, plane_rows), _first_inside(cell, plane_cols)
    along_x = _axis_basis(planes, plane_cols, first_x, inner)  # (parity, plane, k, u)
    along_y = _axis_basis(planes, plane_rows, first_y, inner)
    scale = np.array([lat.scale for lat in planes])[None, :, None, None]
    row_basis = np.concatenate([along_x.real, along_x.imag], axis=2) * scale
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
        window_y=_window_inside(_window_factors(cell, span, plane_rows), first_y, inner),
        window_x=_window_inside(_window_factors(cell, span, plane_cols), first_x, inner),
        row_basis=np.ascontiguousarray(row_basis.transpose(0, 1, 3, 2), dtype=np.float32),
        col_basis=np.stack([along_y.real, along_y.imag], axis=2).astype(np.float32),
        colours=_colour_table(planes, fset, sizes),
        positions=(16 * fset.kv + fset.kh).astype(np.uint64),
        roots=_colour_roots(colour_weights, fset, sizes),
        angles=angles.astype(np.float32),
        pad=pad,
    )


def _axis_basis(
    planes: Sequence[Lattice], offsets: NDArray[np.intp], first: NDArray[np.int64], inner: int
) -> NDArray[np.complex128]:
    """``(parities, planes, 8, inner)``: the basis along one axis at each plane's samples.

    Sample j of plane p inside a tile of start parity q lies at footprint sample
    ``first[q, p] + j``, i.e. at ``step (first + j) + offset`` from the footprint's start.
    """
    step = planes[0].step
    e = _extended_basis(step * (inner + 2))
    out = np.empty((first.shape[0], len(planes), 8, inner), dtype=np.complex128)
    for q in range(first.shape[0]):
        for p in range(len(planes)):
            out[q, p] = e[:, step * (first[q, p] + np.arange(inner)) + offsets[p]]
    return out


def _window_inside(factors: F32, first: NDArray[np.int64], inner: int) -> F32:
    """``(parities, planes, 2, inner)``: the window factors at the samples inside the tile."""
    out = np.empty((*factors.shape[:3], inner), dtype=np.float32)
    for q in range(first.shape[0]):
        for p in range(first.shape[1]):
            out[q, p] = factors[q, p, :, first[q, p] : first[q, p] + inner]
    return out


def _colour_table(
    planes: Sequence[Lattice], fset: FrequencySet, sizes: tuple[int, ...]
) -> NDArray[np.int64]:
    """``(colours, 4)``: first plane, end plane, frequencies, kv count of each colour."""
    out = np.zeros((len(sizes), 4), dtype=np.int64)
    colour = np.array([lat.colour for lat in planes])
    for c, n in enumerate(sizes):
        members = np.nonzero(colour == c)[0]
        out[c] = members[0], members[-1] + 1, n, int(fset.kv[:n].max()) + 1
    return out


def _colour_roots(
    colour_weights: NDArray[np.floating], fset: FrequencySet, sizes: tuple[int, ...]
) -> F32:
    """``(colours, 2, F)``: square root of each colour's weight per (which, f), 0 past F_c.

    A pair product of two cameras' spectra then carries the weight once.
    """
    out = np.zeros((len(sizes), 2, fset.size), dtype=np.float32)
    for c, n in enumerate(sizes):
        wgt = colour_weights[c][fset.kh[:n], :, fset.kv[:n]]  # (F_c, which)
        out[c, :, :n] = np.sqrt(np.maximum(wgt.T, 0.0))
    return out


def _first_inside(cell: int, offsets: NDArray[np.intp]) -> NDArray[np.int64]:
    """``(parities, planes)``: the first footprint sample inside the tile along an axis.

    Sample j of a plane with cell offset o lies at tile-local ``cell j + o - parity``.
    """
    parity = np.arange(cell)[:, None]
    out: NDArray[np.int64] = np.maximum(0, -((offsets[None, :] - parity) // cell)).astype(np.int64)
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
    image: F32,
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
    image
        The camera's ``(H, W)`` image.
    tr
        :func:`camera_transform` of the sensor.
    at
        Where the camera's tiles lie on the sensor.
    """
    t = at.left_x.shape[0]
    packed = np.empty((t, spectrum_floats(tr)), dtype=np.float32)
    shifts = raw_spectra(image, tr, at, packed, kernels=kernels, kernel_index=kernel_index)
    phase = _rotations(shifts, tr)
    return [
        (v[:, :, 0] + 1j * v[:, :, 1]).astype(np.complex64) * phase[:, :, : v.shape[3]]
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
    image: F32,
    tr: CameraTransform,
    at: TilePlacement,
    out: F32,
    *,
    kernels: list[C64] | None = None,
    kernel_index: NDArray[np.intp] | None = None,
) -> F32:
    """One camera's colour spectra before the phase rotation, into ``out``; the rotation.

    Each tile's samples inside the tile are gathered, windowed and transformed in one
    compiled pass (:func:`elphel_host.tp.fused.tile_spectra`). ``kernels`` and
    ``kernel_index`` as in :func:`camera_spectra`.

    Parameters
    ----------
    image, tr, at
        As in :func:`camera_spectra`.
    out
        ``(T, spectrum_floats(tr))`` float32, row t for tile t, filled with the colours
        one after the other, each ``(which, re/im, f)`` (the layout of
        :func:`colour_views`).

    Returns
    -------
    numpy.ndarray
        ``(T, 2)`` float32: the shift (x, y) each tile's spectra still need to be rotated
        by (the fractional shift less the start parity).
    """
    # the compiled kernels load on first use: commands that never run a pass skip numba
    from elphel_host.tp.fused import tile_spectra

    c, span, pc = tr.cell, tr.span, tr.pad // tr.cell
    img = np.ascontiguousarray(image, dtype=np.float32)
    if img.ndim != 2 or img.shape[0] % c or img.shape[1] % c:
        raise ValueError(f"image {img.shape}; allowed: 2-D, sides multiples of {c}")
    t = at.left_x.shape[0]
    # cell-aligned footprint: an odd start is one cell earlier, its samples at 1..16; cells
    # counted from the first of the padding (tr.pad pixels of repeated border each side)
    place = np.empty((4, t), dtype=np.int64)
    place[2] = at.top_y & (c - 1)
    place[3] = at.left_x & (c - 1)
    place[0] = np.clip((at.top_y + tr.pad - place[2]) // c, 0, img.shape[0] // c + 2 * pc - span)
    place[1] = np.clip((at.left_x + tr.pad - place[3]) // c, 0, img.shape[1] // c + 2 * pc - span)
    tile_spectra(
        img,
        np.stack([tr.plane_rows, tr.plane_cols]).astype(np.int64),
        pc,
        place,
        np.stack([at.shift_y, at.shift_x]).astype(np.float64),
        tr.window_y,
        tr.window_x,
        tr.row_basis,
        tr.col_basis,
        tr.first_y,
        tr.first_x,
        tr.colours,
        tr.positions,
        tr.roots,
        out,
    )
    if kernels is not None and kernel_index is not None:
        for colour, n in enumerate(tr.colour_sizes):
            _convolve(colour_views(out, tr)[colour], kernels[colour][kernel_index][:, :, :n])
    shifts = np.empty((t, 2), dtype=np.float32)
    shifts[:, 0] = at.shift_x - place[3]
    shifts[:, 1] = at.shift_y - place[2]
    return shifts


def _convolve(planar: F32, kernel: C64) -> None:
    """Multiply planar spectra ``(T, 2, 2, F)`` (which, re/im, f) by complex ``(T, 2, F)``."""
    re, im = planar[:, :, 0].copy(), planar[:, :, 1]
    planar[:, :, 0] = re * kernel.real - im * kernel.imag
    planar[:, :, 1] = re * kernel.imag + im * kernel.real


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
