"""The production CLT: every colour of one camera's shifted tiles, batched, on the kept frequencies.

This is what the tile processor runs. It is the reference lattice transform
(:mod:`elphel_host.tp.clt.reference`) reorganised for speed and computes the same numbers
(``tests/host/tp/test_clt_batch.py`` checks it against that and against the tile-by-tile
definition):

* Only the frequencies that survive the colour filters are computed (red and blue: the
  4x4 lowest, below their lattice's alias band; green: ``kh + kv <= green_band``; mono:
  all 64). The box of red/blue frequencies comes first in the frequency list, so red and
  blue are a prefix of green.
* A camera's tile is gathered once as 256 mosaic samples ordered by colour lattice. Which
  colour sits on which tile-local parity depends only on the parity of the tile's integer
  origin (its "class"), so each class has fixed transform matrices that already contain
  the lattice offset j0 (no per-lattice rotation), the colour weight and colour LPF
  (as square roots, so a pair product carries them once), and, for green, the sum of the
  two green lattices. Tiles are grouped by class within a chunk.
* The shifted window is ``w_s(j) = cos(pi s/16) w0(j) + sin(pi s/16) w1(j)``, so the 2-D
  window of every tile is a 4-term combination of fixed windows: one small matrix product.
* What is left per tile is one phase rotation by the camera's fractional shift, common to
  all colours.
"""

from __future__ import annotations

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
class _ClassPlan:
    offsets: NDArray[np.int64]  # (256,) flat offsets of the samples in the padded image
    windows: F32  # (4, 256) fixed windows w_a(y) w_b(x)
    blocks: tuple[tuple[slice, F32], ...]  # per colour: samples, matrix (n, 2*2*F_c)


@dataclass(frozen=True)
class CameraTransform:
    """Everything fixed about turning one camera's mosaic into colour spectra."""

    fset: FrequencySet
    colour_sizes: tuple[int, ...]  # frequencies per colour (R, B, G) or (mono,)
    plans: tuple[_ClassPlan, ...]  # index = (top parity) * 2 + (left parity)
    angles: F32  # (2, 2F): rotation angle per (shift_x, shift_y) for (which, f)
    row_stride: int
    pad: int


def _lattice_matrix(
    lat: Lattice, py: int, px: int, fset: FrequencySet, nf: int
) -> NDArray[np.float64]:
    """Samples (v, u) of one lattice at tile-local parity (py, px) -> (which, f, re/im)."""
    st = lat.step
    n = lat.samples
    ys = st * np.arange(n) + py
    xs = st * np.arange(n) + px
    ev = E_COMPLEX[fset.kv[:nf]][:, ys]  # (F, n)
    eh = E_COMPLEX[fset.kh[:nf]][:, xs]  # (F, n)
    z2 = ev[:, :, None] * eh[:, None, :]  # (F, v, u)
    z1 = np.conj(ev)[:, :, None] * eh[:, None, :]
    coef = np.stack([z2, z1]).reshape(2, nf, n * n)  # (which, f, samples)
    out = np.stack([coef.real, coef.imag], axis=-1)  # (which, f, samples, re/im)
    return out.transpose(2, 0, 1, 3).reshape(n * n, 2 * nf * 2) * lat.scale


def camera_transform(
    bayer: str | None,
    colour_weights: NDArray[np.floating],
    *,
    green_band: int,
    pad: int,
    row_stride: int,
) -> CameraTransform:
    """Prepare the class plans of a sensor.

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
    row_stride
        Width of the padded mosaic.
    """
    if pad % 2:
        raise ValueError(f"pad={pad}; allowed: even (keeps the Bayer parity)")
    fset = frequency_set(bayer, green_band=green_band)
    lats = lattices(bayer)
    ncol = 1 if bayer is None else 3
    sizes = tuple(fset.size if (bayer is None or c == 2) else fset.n_box for c in range(ncol))
    w0 = lambda j: np.sin(np.pi * (j + 0.5) / TILE)  # noqa: E731
    w1 = lambda j: np.cos(np.pi * (j + 0.5) / TILE)  # noqa: E731
    plans = []
    for cls in range(4 if bayer is not None else 1):
        cy, cx = cls // 2, cls % 2
        offsets, wins, blocks = [], [], []
        start = 0
        for colour in range(ncol):
            members = [lat for lat in lats if lat.colour == colour]
            mats = []
            for lat in members:
                py, px = (lat.row - cy) % lat.step, (lat.col - cx) % lat.step
                ys = lat.step * np.arange(lat.samples) + py
                xs = lat.step * np.arange(lat.samples) + px
                yy, xx = (a.ravel() for a in np.meshgrid(ys, xs, indexing="ij"))
                offsets.append(yy * row_stride + xx)
                wins.append(
                    np.stack([w0(yy) * w0(xx), w0(yy) * w1(xx), w1(yy) * w0(xx), w1(yy) * w1(xx)])
                )
                mats.append(_lattice_matrix(lat, py, px, fset, sizes[colour]))
            m = np.concatenate(mats, axis=0)
            # fold in the square root of the colour weight: the pair product then carries it once
            wgt = colour_weights[colour][
                fset.kh[: sizes[colour]], :, fset.kv[: sizes[colour]]
            ]  # (F, which)
            root = np.sqrt(np.maximum(wgt.T, 0.0))  # (which, F)
            m = m * np.repeat(root.ravel(), 2)[None, :]
            n_in = m.shape[0]
            blocks.append((slice(start, start + n_in), m.astype(np.float32)))
            start += n_in
        plans.append(
            _ClassPlan(
                offsets=np.concatenate(offsets).astype(np.int64),
                windows=np.concatenate(wins, axis=1).astype(np.float32),
                blocks=tuple(blocks),
            )
        )
    f = fset.size
    angles = np.zeros((2, 2 * f))
    angles[0] = np.tile(OMEGA[fset.kh], 2)
    angles[1] = np.concatenate([OMEGA[fset.kv], -OMEGA[fset.kv]])
    return CameraTransform(
        fset=fset,
        colour_sizes=sizes,
        plans=tuple(plans),
        angles=angles.astype(np.float32),
        row_stride=row_stride,
        pad=pad,
    )


def padded_mosaic(image: NDArray[np.floating], pad: int, *, bayer: bool) -> F32:
    """The image padded by ``pad`` pixels and flattened row-major.

    Out-of-image samples repeat the border pixel of the same Bayer parity (reference 1).
    """
    img = np.asarray(image, dtype=np.float32)
    if bayer:
        if pad % 2:
            raise ValueError(f"pad={pad}; allowed: even for a Bayer mosaic")
        # same-parity clamp = the first (last) two rows/columns repeated
        rows = np.concatenate(
            [np.tile(img[:2], (pad // 2, 1)), img, np.tile(img[-2:], (pad // 2, 1))]
        )
        full = np.concatenate(
            [np.tile(rows[:, :2], (1, pad // 2)), rows, np.tile(rows[:, -2:], (1, pad // 2))],
            axis=1,
        )
    else:
        full = np.pad(img, pad, mode="edge")
    out: F32 = np.ascontiguousarray(full).ravel()
    return out


def camera_spectra(
    flat: F32,
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
    flat
        :func:`padded_mosaic` of the camera.
    tr
        :func:`camera_transform` of the sensor.
    at
        Where the camera's tiles lie on the sensor.
    """
    left_x, shift_x, top_y, shift_y = at.left_x, at.shift_x, at.top_y, at.shift_y
    t = left_x.shape[0]
    nrows = flat.size // tr.row_stride
    lx = np.clip(left_x + tr.pad, 0, tr.row_stride - TILE)
    ly = np.clip(top_y + tr.pad, 0, nrows - TILE)
    base = ly * tr.row_stride + lx
    cls = ((top_y & 1) * 2 + (left_x & 1)) if len(tr.plans) == 4 else np.zeros(t, dtype=np.int64)
    outs = [np.empty((t, 2 * n), dtype=np.complex64) for n in tr.colour_sizes]
    a = np.pi / TILE
    coef = np.empty((t, 4), dtype=np.float32)
    cy, sy = np.cos(a * shift_y), np.sin(a * shift_y)
    cx, sx = np.cos(a * shift_x), np.sin(a * shift_x)
    coef[:, 0] = cy * cx
    coef[:, 1] = cy * sx
    coef[:, 2] = sy * cx
    coef[:, 3] = sy * sx
    uniform_shift = bool(np.ptp(shift_x) == 0 and np.ptp(shift_y) == 0)  # e.g. a first pass
    present = np.unique(cls)
    for c in present:
        plan = tr.plans[int(c)]
        sel = None if present.size == 1 else np.nonzero(cls == c)[0]
        b = base if sel is None else base[sel]
        samples = np.take(flat, b[:, None] + plan.offsets[None, :])
        if uniform_shift:
            samples *= coef[:1] @ plan.windows  # one window for all tiles
        else:
            samples *= (coef if sel is None else coef[sel]) @ plan.windows
        for colour, (rows, mat) in enumerate(plan.blocks):
            z = (samples[:, rows] @ mat).view(np.complex64)
            if sel is None:
                outs[colour] = z
            else:
                outs[colour][sel] = z
    # one rotation by the fractional shift, shared by all colours (box frequencies first)
    shifts = np.stack([shift_x, shift_y], axis=1).astype(np.float32)
    ang = (shifts[:1] if uniform_shift else shifts) @ tr.angles  # (T or 1, 2F)
    phase = np.empty(ang.shape, dtype=np.complex64)
    phase.real = np.cos(ang)
    phase.imag = np.sin(ang)
    f = tr.fset.size
    phase3 = phase.reshape(-1, 2, f)
    result = []
    for colour, n in enumerate(tr.colour_sizes):
        z = outs[colour].reshape(t, 2, n)
        if kernels is not None and kernel_index is not None:
            z *= kernels[colour][kernel_index][:, :, :n]
        z *= phase3[:, :, :n]
        result.append(z)
    return result


def expand(products: C64, fset: FrequencySet) -> C64:
    """Compact products ``(..., 2, F)`` -> full layout ``(..., 8, 2, 8)`` (zeros elsewhere)."""
    out = np.zeros((*products.shape[:-2], 8, 2, 8), dtype=np.complex64)
    out[..., fset.kh, 0, fset.kv] = products[..., 0, :]
    out[..., fset.kh, 1, fset.kv] = products[..., 1, :]
    return out
