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
