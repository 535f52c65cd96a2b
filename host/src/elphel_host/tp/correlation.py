"""Batched CLT-domain phase correlation of the quad pairs and its sub-pixel maximum.

Everything here works on chunks of tiles as arrays. The per-camera spectra use the
complex form of the CLT (see :mod:`elphel_host.tp.clt`): one tile-colour is an array
``(8 kh, 2, 8 kv)`` of complex numbers, ``[..., 0, :] = z2`` and ``[..., 1, :] = z1``.

A colour lattice (8x8 samples of a Bayer colour, or 16x16 of a mono sensor) is
transformed as if its samples sat on the even tile positions; the true offset j0 (0 or
1) is added to the fractional shift, since moving the samples by one pixel is exactly a
phase rotation by s = 1 (``E[k, n+1] = E[k, n] exp(i pi (2k+1)/16)``). The fractional part
of each camera's tile position is the shifted window plus the same rotation (reference
2.5), so the images are never resampled.

The pair product (conjugate of the first camera), the fat-zero normalisation and the
correlation LPF follow reference 6.2-6.4. The 15x15 pixel-domain correlation of 6.4 is a
real Fourier series in the lag (dx, dy)::

    R(dy, dx) = 1/32 Re sum_k [P2 exp(-i(wh dx + wv dy)) + P1 exp(-i(wh dx - wv dy))]

with w(k) = pi (2k+1)/16, so it can be evaluated directly along each pair's disparity
direction (the "strip" of the reference, row 0) at integer disparity steps, summing the
pairs in a common orientation.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from elphel_host.tp.bayer import Lattice
from elphel_host.tp.clt import E_COMPLEX, TILE, N

F32 = NDArray[np.float32]
C64 = NDArray[np.complex64]

OMEGA = np.pi * (2 * np.arange(N) + 1) / TILE  # angular frequency of index k, rad/pixel


def lpf_mask(sigma: float) -> NDArray[np.float64]:
    """Frequency-domain LPF (reference section 5): Gaussian of the lag, as an 8x8 [kv][kh] mask.

    ``f(i, j) = exp(-(i^2 + j^2) / (2 sigma))`` (sigma not squared, as in the reference),
    normalised, then converted with DCT-IIIe and scaled by 16. ``sigma = 0`` gives no
    filtering (all ones).
    """
    if sigma < 0:
        raise ValueError(f"lpf sigma={sigma}; allowed: >= 0")
    if sigma == 0:
        return np.ones((N, N))
    i = np.arange(N)
    f = np.exp(-(i[:, None] ** 2 + i[None, :] ** 2) / (2.0 * sigma))
    c = np.cos(np.pi * i / (2 * N)) * np.where(i > 0, 2.0, 1.0)
    f /= (c[:, None] * c[None, :] * f).sum()
    e = np.ones(N)
    e[0] = e[-1] = 0.5
    c3e = (
        np.sqrt(2.0 / N) * e[None, :] * np.cos(np.pi * i[None, :] * (2 * i[:, None] + 1) / (2 * N))
    )
    out: NDArray[np.float64] = 16.0 * c3e @ f @ c3e.T
    return out


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


def lattice_spectra(
    sub: F32,
    lattice: Lattice,
    left_x: NDArray[np.int64],
    shift_x: NDArray[np.float64],
    top_y: NDArray[np.int64],
    shift_y: NDArray[np.float64],
    *,
    pad: int,
) -> C64:
    """Shifted CLT (complex form) of one lattice of one camera for a batch of tiles.

    Parameters
    ----------
    sub
        The lattice's padded sub-image (:func:`elphel_host.tp.bayer.sublattice`).
    lattice
        Which lattice.
    left_x, top_y
        ``(T,)`` integer first pixel of each tile window on the sensor.
    shift_x, shift_y
        ``(T,)`` residual shifts s in [-0.5, 0.5].
    pad
        Padding of ``sub`` in sub-image samples.

    Returns
    -------
    numpy.ndarray
        ``(T, 8, 2, 8)`` complex64: [kh, (z2, z1), kv].
    """
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


def pair_products(
    spectra: C64, pairs: tuple[tuple[int, int], ...], weights: NDArray[np.floating]
) -> C64:
    """Colour-weighted CLT-domain products of camera pairs (first camera conjugated).

    Parameters
    ----------
    spectra
        ``(T, cameras, colours, 8, 2, 8)``.
    pairs
        (first, second) camera indices.
    weights
        Per-colour weights ``(colours,)``, or per-colour frequency weights
        ``(colours, 8, 2, 8)`` (a colour LPF).

    Returns
    -------
    numpy.ndarray
        ``(T, pairs, 8, 2, 8)`` complex64.
    """
    t = spectra.shape[0]
    ncol = spectra.shape[2]
    w = np.asarray(weights, dtype=np.float32)
    if w.shape not in ((ncol,), (ncol, *spectra.shape[3:])):
        raise ValueError(f"weights shape {w.shape}; allowed: ({ncol},) or ({ncol}, 8, 2, 8)")
    out = np.empty((t, len(pairs), *spectra.shape[3:]), dtype=np.complex64)
    for p, (a, b) in enumerate(pairs):
        acc = out[:, p]
        for c in range(ncol):
            term = np.conj(spectra[:, a, c])
            term *= spectra[:, b, c]
            if c == 0:
                np.multiply(term, w[c], out=acc)
            else:
                term *= w[c]
                acc += term
    return out


def normalise(products: C64, fat_zero: float) -> C64:
    """Phase-correlation normalisation with a fat zero, in place (GPU variant of reference 6.3).

    Each frequency (the 4 quadrants together, i.e. z1 and z2 together) is divided by
    ``sqrt(fat_zero^2 + |P|^2)``, so strong frequencies keep only their phase and weak
    ones (below the fat zero, e.g. noise in texture-less tiles) are suppressed.
    """
    mag = products.real**2
    mag += products.imag**2
    m = mag[..., 0, :] + mag[..., 1, :]
    m *= 0.5
    m += np.float32(fat_zero) ** 2
    np.sqrt(m, out=m)
    np.reciprocal(m, out=m)
    products *= m[..., None, :]
    return products


@dataclass(frozen=True)
class Profiles:
    """Correlation sampled along each pair's disparity direction.

    ``basis[p]`` maps a pair's normalised product (256 reals) to: its correlation at the
    residual disparities ``lags`` (pixels), then its first and its second derivative by
    the residual disparity at ``deriv_lags``. The LPF is applied and the scale is such
    that identical tiles give 1 at lag 0.
    """

    lags: NDArray[np.float64]
    deriv_lags: NDArray[np.float64]
    basis: tuple[F32, ...]


def profile_basis(
    pair_vectors: NDArray[np.float64],
    lags: NDArray[np.float64],
    *,
    lpf_sigma: float,
    deriv_lags: NDArray[np.float64] | None = None,
) -> Profiles:
    """Build :class:`Profiles` for given pair directions (from ``QuadGeometry.pair_vectors``)."""
    lags = np.asarray(lags, dtype=np.float64)
    dl = (
        np.array([-1.0, 0.0, 1.0])
        if deriv_lags is None
        else np.asarray(deriv_lags, dtype=np.float64)
    )
    lpf = lpf_mask(lpf_sigma)  # [kv][kh]
    norm = lpf.sum() / 16.0
    weight = lpf.T[None, :, None, :] / (32.0 * norm)  # (1, kh, which, kv)
    sign_v = np.array([1.0, -1.0])[None, None, :, None]
    mats = []
    for ex, ey in pair_vectors:
        # angular frequency of each coefficient along the residual disparity (kh, which, kv)
        phi = ex * OMEGA[None, :, None, None] + ey * OMEGA[None, None, None, :] * sign_v

        def block(
            d: NDArray[np.float64], order: int, phi: NDArray[np.float64] = phi
        ) -> NDArray[np.float64]:
            ph = d[:, None, None, None] * phi
            c, s = np.cos(ph), np.sin(ph)
            # d^n/dd^n of Re(P exp(-i phi d)) = Pr cos + Pi sin, differentiated n times
            re, im = [(c, s), (-phi * s, phi * c), (-phi * phi * c, -phi * phi * s)][order]
            m = np.empty((d.size, N, 2, N, 2))
            m[..., 0] = re * weight
            m[..., 1] = im * weight
            return m.reshape(d.size, -1)

        full = np.concatenate([block(lags, 0), block(dl, 1), block(dl, 2)])
        mats.append(full.T.astype(np.float32))
    return Profiles(lags=lags, deriv_lags=dl, basis=tuple(mats))


def window_envelope(
    lags: NDArray[np.float64], pair_vectors: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Overlap of two sine-windowed tiles shifted by each lag along each pair: ``(pairs, lags)``.

    A correlation peak at lag d is attenuated by about this factor (the tiles share only
    part of their content), so dividing by it levels far peaks with near ones when the
    integer maximum is chosen.
    """
    a = np.pi / TILE

    def one(t: NDArray[np.float64]) -> NDArray[np.float64]:
        t = np.minimum(np.abs(t), TILE)
        rest = TILE - t
        val: NDArray[np.float64] = 0.5 * (
            rest * np.cos(a * t) - (np.sin(a * (2 * rest + t)) - np.sin(a * t)) / (2 * a)
        )
        return val / 8.0

    return np.stack([one(lags * ex) * one(lags * ey) for ex, ey in pair_vectors])


def pair_profiles(products: C64, profiles: Profiles) -> F32:
    """Per pair: correlation at ``lags``, then derivatives 1 and 2 at ``deriv_lags``."""
    t, npairs = products.shape[:2]
    real = products.view(np.float32).reshape(t, npairs, -1)
    out = np.empty((t, npairs, profiles.basis[0].shape[1]), dtype=np.float32)
    for p in range(npairs):
        out[:, p] = real[:, p] @ profiles.basis[p]
    return out


def correlation_2d(products: C64, *, lpf_sigma: float, radius: int = 7) -> F32:
    """Pixel-domain correlation tiles (2r+1)^2 of each pair, in its native orientation.

    Returns
    -------
    numpy.ndarray
        ``(T, pairs, 2r+1, 2r+1)`` float32, row = 7 + dy, column = 7 + dx, normalised so
        identical tiles give 1 at the centre.
    """
    lpf = lpf_mask(lpf_sigma)
    norm = lpf.sum() / 16.0
    d = np.arange(-radius, radius + 1, dtype=np.float64)
    eh = np.exp(-1j * d[:, None] * OMEGA[None, :])  # (dx, kh)
    ev = np.exp(-1j * d[:, None] * OMEGA[None, :])  # (dy, kv)
    p = products * (lpf.T[:, None, :] / (32.0 * norm)).astype(np.float32)
    z2 = p[..., 0, :]  # (..., kh, kv)
    z1 = p[..., 1, :]
    r = np.einsum("yv,...hv,xh->...yx", ev, z2, eh) + np.einsum(
        "yv,...hv,xh->...yx", np.conj(ev), z1, eh
    )
    out: F32 = r.real.astype(np.float32)
    return out


def subpixel_max(
    samples: F32,
    profiles: Profiles,
    *,
    lag_min: NDArray[np.floating] | None = None,
    select: F32 | None = None,
) -> tuple[F32, F32, NDArray[np.intp]]:
    """Sub-pixel maximum of correlation profiles.

    The integer maximum over ``lags`` is refined by a Gaussian fit when it falls on one of
    ``deriv_lags`` (the fit uses the exact value, slope and curvature there: the log of
    the peak is taken as a parabola, exact for a Gaussian peak), else by the parabola
    through the maximum and its two neighbours.

    Parameters
    ----------
    samples
        ``(..., L + 2 D)`` as returned by :func:`pair_profiles` (averaged over pairs).
    profiles
        The basis used.
    lag_min
        Optional ``(...)`` smallest residual allowed per profile (e.g. no disparity
        beyond infinity); lags below it are not searched.
    select
        Optional ``(..., L)`` profile whose integer maximum is used instead (e.g. the
        profile divided by the window-overlap envelope).

    Returns
    -------
    position, value, index
        Peak position (residual disparity, pixels), value at the peak, integer argmax.
    """
    lags = profiles.lags
    nl = lags.size
    nd = profiles.deriv_lags.size
    prof = samples[..., :nl]
    search = prof if select is None else select
    if lag_min is not None:
        search = np.where(lags < np.asarray(lag_min)[..., None] - 0.5, np.float32(-np.inf), search)
    idx = np.argmax(search, axis=-1)
    inner = np.clip(idx, 1, nl - 2)

    def at(i: NDArray[np.intp], arr: F32 = prof) -> F32:
        out: F32 = np.take_along_axis(arr, i[..., None], axis=-1)[..., 0]
        return out

    c0, cm, cp = at(inner), at(inner - 1), at(inner + 1)
    with np.errstate(invalid="ignore"):
        curv = cm + cp - 2.0 * c0
    ok = (curv < 0) & (idx == inner)
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.clip(np.where(ok, 0.5 * (cm - cp) / np.where(ok, curv, -1.0), 0.0), -0.5, 0.5)
        value = np.where(ok, c0 - 0.25 * (cm - cp) * frac, at(idx))
    pos = lags[0] + idx + frac
    # Gaussian (log-parabola) fit from exact derivatives where available
    lag_of_idx = lags[idx]
    j = np.searchsorted(profiles.deriv_lags, lag_of_idx)
    j = np.clip(j, 0, nd - 1)
    has = profiles.deriv_lags[j] == lag_of_idx
    g = at(idx)
    g1 = at(j, samples[..., nl : nl + nd])
    g2 = at(j, samples[..., nl + nd : nl + 2 * nd])
    den = g * g2 - g1 * g1
    good = has & (g > 0) & (den < 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        step = np.where(good, -g * g1 / np.where(good, den, -1.0), 0.0)
        good &= np.abs(step) <= 1.0
        # peak of exp(L0 + L1 x + L2 x^2 / 2): L1 = g1/g, L2 = den/g^2
        lg_peak = np.where(good, 0.5 * g1 * step / np.where(good, g, 1.0), 0.0)
    pos = np.where(good, lag_of_idx + step, pos)
    if lag_min is not None:
        pos = np.maximum(pos, np.asarray(lag_min) - 0.5)
    value = np.where(good, g * np.exp(lg_peak), value)
    return pos.astype(np.float32), value.astype(np.float32), idx


def windowed_centroid(
    samples: F32, profiles: Profiles, index: NDArray[np.intp], *, half_width: int = 2
) -> F32:
    """Centre of mass of the positive samples within +-half_width of the integer maximum."""
    lags = profiles.lags
    nl = lags.size
    profile = samples[..., :nl]
    offs = np.arange(-half_width, half_width + 1)
    pos = index[..., None] + offs
    valid = (pos >= 0) & (pos < nl)
    vals = np.take_along_axis(profile, np.clip(pos, 0, nl - 1), axis=-1)
    # half-flat-top taper, so samples entering the window do not make the centroid jump
    taper = np.cos(0.5 * np.pi * offs / (half_width + 1)) ** 2
    wgt = np.where(valid, np.maximum(vals, 0.0), 0.0) * taper
    s0 = wgt.sum(-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(s0 > 0, (wgt * offs).sum(-1) / s0, 0.0)
    out: F32 = (lags[0] + index + c).astype(np.float32)
    return out
