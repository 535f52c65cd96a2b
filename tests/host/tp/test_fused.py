"""The fused pair-product kernel equals rotating each camera, then the NumPy pair products.

`fused.rotated_pair_products` sums the colour products of each pair, normalises them
with the fat zero and applies both cameras' phase rotations, per tile. Built here from
its definition: each camera's colour spectra rotated by ``exp(i (x w(kh) +- y w(kv)))``,
then `correlation.compact_pair_products` and `correlation.normalise`.
"""

from __future__ import annotations

import numpy as np
import pytest

from elphel_host.tp import fused
from elphel_host.tp.clt import OMEGA
from elphel_host.tp.clt.batch import frequency_set
from elphel_host.tp.correlation import (
    Profiles,
    _gaussian_peak,
    centroid_taper,
    compact_pair_products,
    integer_max,
    normalise,
    subpixel_max,
    windowed_centroid,
)
from elphel_host.tp.geometry import PAIRS

# Products normalised to modulus <= sqrt(2); the kernel builds each rotation by a float32
# recurrence of up to 7 complex products (~1e-7 relative each) for each of two cameras,
# the reference by float64 exponentials: they differ by up to ~2e-6 (measured 2.2e-6).
# A wrong sign or frequency index gives differences of order 1.
TOL = 5e-6


def _planar_to_complex(planar: np.ndarray) -> np.ndarray:
    """(..., which, re/im, f) float32 -> (..., which, f) complex64."""
    return (planar[..., 0, :] + 1j * planar[..., 1, :]).astype(np.complex64)


@pytest.mark.parametrize("bayer", [None, "GRBG"])
@pytest.mark.parametrize("fat_zero", [0.0, 0.3])
def test_kernel_equals_rotation_then_numpy_products(bayer: str | None, fat_zero: float) -> None:
    rng = np.random.default_rng(7)
    fset = frequency_set(bayer, green_band=5)
    sizes = [fset.size] if bayer is None else [fset.n_box, fset.n_box, fset.size]
    t, ncam = 37, 4
    planar = [
        [rng.normal(size=(t, 2, 2, n)).astype(np.float32) for n in sizes] for _ in range(ncam)
    ]
    shifts = rng.uniform(-1.5, 0.5, size=(ncam, t, 2)).astype(np.float32)
    spectra = np.empty((ncam, t, 4 * sum(sizes)), dtype=np.float32)
    for c in range(ncam):
        spectra[c] = np.concatenate([p.reshape(t, -1) for p in planar[c]], axis=1)
    angle = (np.pi / 16) * shifts
    rotation = np.stack([np.cos(angle), np.sin(angle)], axis=-1).astype(np.float32)
    out = np.empty((len(PAIRS), t, 2, 2, fset.size), dtype=np.float32)
    fused.rotated_pair_products(
        spectra,
        rotation,
        np.array(PAIRS, dtype=np.int64),
        fset.kh.astype(np.int64),
        fset.kv.astype(np.int64),
        np.array(sizes, dtype=np.int64),
        np.float32(fat_zero),
        out,
    )
    rotated = []
    for c in range(ncam):
        x, y = shifts[c, :, 0:1].astype(np.float64), shifts[c, :, 1:2].astype(np.float64)
        wh, wv = OMEGA[fset.kh][None, :], OMEGA[fset.kv][None, :]
        phase = np.stack([np.exp(1j * (x * wh + y * wv)), np.exp(1j * (x * wh - y * wv))], 1)
        rotated.append(
            [
                _planar_to_complex(p) * phase[:, :, :n].astype(np.complex64)
                for p, n in zip(planar[c], sizes, strict=True)
            ]
        )
    expected = normalise(compact_pair_products(rotated, PAIRS, fset), fat_zero)
    got = _planar_to_complex(out).transpose(1, 0, 2, 3)
    assert np.abs(expected).max() > 0.5  # the comparison is not of near-zero values
    np.testing.assert_allclose(got, expected, atol=TOL, rtol=0)


def _peaked_profiles(rng: np.random.Generator, t: int, npairs: int) -> np.ndarray:
    """Pair profiles ``(T, P, 15 + 3 + 3)``: Gaussian peaks with their exact derivatives at
    -1, 0, 1 in half the tiles (so the log-parabola fit holds), noise in the other half."""
    lags = np.arange(-7.0, 8.0)
    dl = np.array([-1.0, 0.0, 1.0])
    centre = rng.uniform(-7.5, 7.5, size=(t, npairs, 1))
    width = rng.uniform(0.8, 2.5, size=(t, npairs, 1))

    def g(x: np.ndarray) -> np.ndarray:
        return np.exp(-0.5 * ((x - centre) / width) ** 2)

    u = (dl - centre) / width
    d1 = -u / width * g(dl)
    d2 = (u**2 - 1) / width**2 * g(dl)
    prof = np.concatenate([g(lags), d1, d2], axis=-1)
    noise = rng.normal(size=prof.shape)
    prof[t // 2 :] = noise[t // 2 :]
    return prof.astype(np.float32)


def test_correlation_peaks_equal_the_numpy_reference() -> None:
    rng = np.random.default_rng(11)
    t, npairs = 400, len(PAIRS)
    prof = _peaked_profiles(rng, t, npairs)
    means = np.zeros((4, npairs), dtype=np.float32)
    for g, members in enumerate([[0, 1, 2, 3, 4, 5], [0, 1], [2, 3], [4, 5]]):
        means[g, members] = 1.0 / len(members)
    envelope = rng.uniform(0.05, 1.0, size=(npairs, 15)).astype(np.float32)
    profiles = Profiles(lags=np.arange(-7.0, 8.0), deriv_lags=np.array([-1.0, 0.0, 1.0]), basis=())
    lag_min = rng.uniform(-9.0, 2.0, size=t)  # some searches start above lag -7
    residual = np.empty((t, 4), dtype=np.float32)
    strength = np.empty_like(residual)
    centroid = np.empty(t, dtype=np.float32)
    levelled = np.empty((t, 15), dtype=np.float32)
    fused.correlation_peaks(
        prof,
        means,
        envelope,
        profiles.lags,
        profiles.deriv_lags,
        centroid_taper(),
        lag_min,
        residual,
        strength,
        centroid,
        levelled,
    )
    combined = means @ prof
    select = means @ (prof[:, :, :15] / envelope)
    idx = integer_max(combined, profiles, lag_min=lag_min[:, None], select=select)
    pos, val, _ = subpixel_max(combined, profiles, lag_min=lag_min[:, None], select=select)
    # float32 sums in another order: ~1e-7 relative; a wrong branch moves a peak by > 1e-2
    np.testing.assert_allclose(residual, pos, atol=2e-5, rtol=0)
    np.testing.assert_allclose(strength, val, atol=2e-5, rtol=0)
    np.testing.assert_allclose(
        centroid, windowed_centroid(combined[:, 0], profiles, idx[:, 0]), atol=2e-5, rtol=0
    )
    np.testing.assert_allclose(levelled, select[:, 0], atol=2e-5, rtol=0)
    # the tiles take every branch: Gaussian fits and parabolas, peaks clamped to lag_min
    gaussian = _gaussian_peak(combined, profiles, idx)[0]
    assert 0.1 < gaussian.mean() < 0.9
    assert np.sum(pos == (lag_min[:, None] - 0.5).astype(np.float32)) > 10


def _neighbourhood_reference(
    levelled: np.ndarray, own: np.ndarray, lags: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """`fused.neighbourhood_peaks` by its definition, in NumPy."""
    finite = np.isfinite(levelled)
    p = np.pad(np.where(finite, levelled, 0.0).astype(np.float64), ((1, 1), (1, 1), (0, 0)), "edge")
    ty, tx = levelled.shape[:2]
    smooth = np.zeros((ty, tx, lags.size))
    for dy in range(3):
        for dx in range(3):
            smooth += p[dy : dy + ty, dx : dx + tx]
    smooth = np.where(finite, smooth, -np.inf)
    i = np.argmax(smooth, axis=-1)[..., None]
    top = np.take_along_axis(smooth, i, -1)[..., 0]
    lo = np.take_along_axis(smooth, np.maximum(i - 1, 0), -1)[..., 0]
    hi = np.take_along_axis(smooth, np.minimum(i + 1, lags.size - 1), -1)[..., 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        curv = lo + hi - 2 * top
        frac = np.where(np.isfinite(curv) & (curv < 0), 0.5 * (lo - hi) / curv, 0.0)
        r = lags[i[..., 0]] + np.clip(frac, -0.5, 0.5)
        return np.where(np.abs(own - r) <= 1.0, own, r), top


def test_neighbourhood_peaks_equal_their_definition() -> None:
    rng = np.random.default_rng(5)
    lags = np.arange(-7.0, 8.0)
    centre = rng.uniform(-6, 6, size=(23, 31, 1))
    levelled = (np.exp(-0.5 * (lags - centre) ** 2) + 0.3 * rng.normal(size=(23, 31, 15))).astype(
        np.float32
    )
    levelled[3, 4, 5] = np.nan
    levelled[0, :, :4] = -np.inf  # lags below min_disparity
    levelled[10, 10] = -np.inf
    own = (centre[..., 0] + rng.normal(scale=0.8, size=(23, 31))).astype(np.float32)
    own[7, 8] = np.nan
    residual, peak = np.empty((23, 31)), np.empty((23, 31))
    fused.neighbourhood_peaks(levelled, own, lags, residual, peak)
    want_residual, want_peak = _neighbourhood_reference(levelled, own, lags)
    np.testing.assert_array_equal(residual, want_residual)
    np.testing.assert_array_equal(peak, want_peak)
    assert 0.2 < np.mean(residual == own) < 0.9  # both the own and the neighbourhood's
