"""Batched CLT-domain phase correlation of the quad pairs and its sub-pixel maximum.

Everything here works on chunks of tiles as arrays. The per-camera spectra use the
complex form of the CLT (see :mod:`elphel_host.tp.clt`): one tile-colour is an array
``(8 kh, 2, 8 kv)`` of complex numbers, ``[..., 0, :] = z2`` and ``[..., 1, :] = z1``
(the full layout), or ``(2, F)`` on the frequencies the production path keeps
(the compact layout of :class:`~elphel_host.tp.clt.batch.FrequencySet`).
:func:`pair_products` is the full-layout reference of :func:`compact_pair_products`, and
:func:`profile_basis` of :func:`compact_profiles`. The tile processor forms its pair
products, normalised, in one compiled pass
(:func:`elphel_host.tp.fused.rotated_pair_products`, planar: which, re/im, f), of which
:func:`compact_pair_products` and :func:`normalise` are the NumPy reference.

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

import numpy as np
from numpy.typing import NDArray

from elphel_host.tp.clt.batch import FrequencySet
from elphel_host.tp.clt.transform import OMEGA, TILE, N

F32 = NDArray[np.float32]
C64 = NDArray[np.complex64]


def lpf_mask(sigma: float) -> NDArray[np.float64]:
    """Frequency-domain LPF (Elphel's correlation LPF): Gaussian of the lag, as an 8x8 mask.

    The mask is indexed [kv][kh]. ``f(i, j) = exp(-(i^2 + j^2) / (2 sigma))`` (sigma not
    squared, as in Elphel's code),
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


def compact_pair_products(
    spectra: list[list[C64]], pairs: tuple[tuple[int, int], ...], fset: FrequencySet
) -> C64:
    """Pair products summed over colours, compact layout: ``(T, pairs, 2, F)``.

    The compact form of :func:`pair_products` (and the reference of
    :func:`elphel_host.tp.fused.rotated_pair_products`): the spectra come from
    :func:`~elphel_host.tp.clt.batch.camera_spectra` with the square roots of the colour
    weights already inside, per camera a list of colours ``(T, 2, F_c)`` (red and blue on
    the first ``fset.n_box`` frequencies, green or mono on all). The result is a
    transposed view of a pair-major array (each pair's block contiguous).
    """
    t = spectra[0][0].shape[0]
    ncol = len(spectra[0])
    # pair-major, so each pair's products are one contiguous block (returned transposed)
    buf = np.empty((len(pairs), t, 2, fset.size), dtype=np.complex64)
    conj = {a: [np.conj(z) for z in spectra[a]] for a in sorted({a for a, _ in pairs})}
    # red + blue summed first (contiguous), then added once to green's box, whose view
    # is strided: each strided add costs per row of 16, not per value
    tmp = np.empty((2, t, 2, fset.n_box), dtype=np.complex64)
    for p, (a, b) in enumerate(pairs):
        acc = buf[p]
        np.multiply(conj[a][ncol - 1], spectra[b][ncol - 1], out=acc)  # green/mono: all
        if ncol == 1:
            continue
        np.multiply(conj[a][0], spectra[b][0], out=tmp[0])
        for c in range(1, ncol - 1):
            np.multiply(conj[a][c], spectra[b][c], out=tmp[1])
            tmp[0] += tmp[1]
        acc[:, :, : fset.n_box] += tmp[0]
    out: C64 = buf.transpose(1, 0, 2, 3)
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


def compact_profiles(full: Profiles, fset: FrequencySet, lpf: NDArray[np.floating]) -> Profiles:
    """Restrict a :func:`profile_basis` to the kept frequencies, rows planar.

    Its rows are (which, re/im, f): they take the planar products of
    :func:`elphel_host.tp.fused.rotated_pair_products`. Rescaled so that a normalised
    product of 1 at every kept frequency gives 1 at lag 0.
    """
    rows = [
        ((fset.kh[f] * 2 + which) * 8 + fset.kv[f]) * 2 + part
        for which in range(2)
        for part in range(2)
        for f in range(fset.size)
    ]
    scale = float(lpf.sum()) / float(lpf[fset.kv, fset.kh].sum())
    return Profiles(
        lags=full.lags,
        deriv_lags=full.deriv_lags,
        basis=tuple((b[rows] * scale).astype(np.float32) for b in full.basis),
    )


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


def pair_profiles(products: C64 | F32, profiles: Profiles) -> F32:
    """Per pair: correlation at ``lags``, then derivatives 1 and 2 at ``deriv_lags``.

    ``products`` is ``(T, pairs, ...)``: complex in the layout of the basis's rows
    (:func:`profile_basis`), or float32 already in it (:func:`compact_profiles`).
    """
    t, npairs = products.shape[:2]
    floats = products.view(np.float32) if np.iscomplexobj(products) else products
    real = floats.reshape(t, npairs, -1)
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


def integer_max(
    samples: F32,
    profiles: Profiles,
    *,
    lag_min: NDArray[np.floating] | None = None,
    select: F32 | None = None,
) -> NDArray[np.intp]:
    """Index of the integer maximum over ``lags`` (the first step of :func:`subpixel_max`)."""
    lags = profiles.lags
    search = samples[..., : lags.size] if select is None else select
    if lag_min is not None:
        search = np.where(lags < np.asarray(lag_min)[..., None] - 0.5, np.float32(-np.inf), search)
    out: NDArray[np.intp] = np.argmax(search, axis=-1)
    return out


def subpixel_max(
    samples: F32,
    profiles: Profiles,
    *,
    lag_min: NDArray[np.floating] | None = None,
    select: F32 | None = None,
    index: NDArray[np.intp] | None = None,
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
    index
        The integer maximum if already known (:func:`integer_max` of the same
        arguments); else it is found here.

    Returns
    -------
    position, value, index
        Peak position (residual disparity, pixels), value at the peak, integer argmax.
    """
    nl = profiles.lags.size
    idx = integer_max(samples, profiles, lag_min=lag_min, select=select) if index is None else index
    pos, value = _parabola_peak(samples[..., :nl], profiles.lags, idx)
    good, gauss_pos, gauss_value = _gaussian_peak(samples, profiles, idx)
    pos = np.where(good, gauss_pos, pos)
    if lag_min is not None:
        pos = np.maximum(pos, np.asarray(lag_min) - 0.5)
    value = np.where(good, gauss_value, value)
    return pos.astype(np.float32), value.astype(np.float32), idx


def _at(arr: F32, i: NDArray[np.intp]) -> F32:
    out: F32 = np.take_along_axis(arr, i[..., None], axis=-1)[..., 0]
    return out


def _parabola_peak(
    prof: F32, lags: NDArray[np.float64], idx: NDArray[np.intp]
) -> tuple[NDArray[np.floating], NDArray[np.floating]]:
    """Peak position and value of the parabola through the maximum and its neighbours.

    At the ends of ``lags`` or where the parabola opens upwards, the integer maximum.
    """
    inner = np.clip(idx, 1, lags.size - 2)
    c0, cm, cp = _at(prof, inner), _at(prof, inner - 1), _at(prof, inner + 1)
    with np.errstate(invalid="ignore"):
        curv = cm + cp - 2.0 * c0
    ok = (curv < 0) & (idx == inner)
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.clip(np.where(ok, 0.5 * (cm - cp) / np.where(ok, curv, -1.0), 0.0), -0.5, 0.5)
        value = np.where(ok, c0 - 0.25 * (cm - cp) * frac, _at(prof, idx))
    return lags[0] + idx + frac, value


def _gaussian_peak(
    samples: F32, profiles: Profiles, idx: NDArray[np.intp]
) -> tuple[NDArray[np.bool_], NDArray[np.floating], NDArray[np.floating]]:
    """Gaussian (log-parabola) fit from the exact derivatives at the integer maximum.

    Returns where the fit holds (the maximum is on ``deriv_lags``, the log opens downwards,
    the step is at most 1 px), and the peak position and value there.
    """
    lags = profiles.lags
    nl = lags.size
    nd = profiles.deriv_lags.size
    lag_of_idx = lags[idx]
    j = np.clip(np.searchsorted(profiles.deriv_lags, lag_of_idx), 0, nd - 1)
    has = profiles.deriv_lags[j] == lag_of_idx
    g = _at(samples[..., :nl], idx)
    g1 = _at(samples[..., nl : nl + nd], j)
    g2 = _at(samples[..., nl + nd : nl + 2 * nd], j)
    den = g * g2 - g1 * g1
    good = has & (g > 0) & (den < 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        step = np.where(good, -g * g1 / np.where(good, den, -1.0), 0.0)
        good &= np.abs(step) <= 1.0
        # peak of exp(L0 + L1 x + L2 x^2 / 2): L1 = g1/g, L2 = den/g^2
        lg_peak = np.where(good, 0.5 * g1 * step / np.where(good, g, 1.0), 0.0)
    return good, lag_of_idx + step, g * np.exp(lg_peak)


def centroid_taper(half_width: int = 2) -> NDArray[np.float64]:
    """Weights of :func:`windowed_centroid` at offsets ``-half_width..half_width``.

    A half-flat-top taper, so samples entering the window do not make the centroid jump.
    """
    offs = np.arange(-half_width, half_width + 1)
    out: NDArray[np.float64] = np.cos(0.5 * np.pi * offs / (half_width + 1)) ** 2
    return out


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
    taper = centroid_taper(half_width)
    wgt = np.where(valid, np.maximum(vals, 0.0), 0.0) * taper
    s0 = wgt.sum(-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(s0 > 0, (wgt * offs).sum(-1) / s0, 0.0)
    out: F32 = (lags[0] + index + c).astype(np.float32)
    return out
