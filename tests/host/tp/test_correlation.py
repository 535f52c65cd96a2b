"""CLT-domain correlation: the complex products against the reference formulas, sign, sub-pixel."""

from __future__ import annotations

import numpy as np
import pytest

from elphel_host.tp import clt, correlation
from elphel_host.tp.geometry import QuadGeometry, place

N = 8
_m = np.arange(N)[:, None]
_k = np.arange(N)[None, :]
C2E = np.sqrt(2 / N) * np.cos(np.pi * _m * (2 * _k + 1) / (2 * N))
S2E = np.sqrt(2 / N) * np.sin(np.pi * (_m + 1) * (2 * _k + 1) / (2 * N))


def reference_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Reference 6.2 quadrant product, conjugate of the first tile."""
    acc, asc, acs, ass = a
    bcc, bsc, bcs, bss = b
    return np.stack(
        [
            acc * bcc + asc * bsc + acs * bcs + ass * bss,
            -asc * bcc + acc * bsc - ass * bcs + acs * bss,
            -acs * bcc - ass * bsc + acc * bcs + asc * bss,
            ass * bcc - acs * bsc - asc * bcs + acc * bss,
        ]
    )


def reference_unfold(p: np.ndarray) -> np.ndarray:
    """Reference 6.4: quadrants -> 15x15 pixel-domain correlation."""
    q = []
    for i in range(4):
        tv = S2E if i & 2 else C2E
        th = S2E if i & 1 else C2E
        q.append(tv @ p[i] @ th.T)
    out = np.zeros((15, 15))
    for dy in range(-7, 8):
        for dx in range(-7, 8):
            sx, sy = np.sign(dx), np.sign(dy)
            v = q[0][abs(dy), abs(dx)]
            if dx:
                v += sx * q[1][abs(dy), abs(dx) - 1]
            if dy:
                v += sy * q[2][abs(dy) - 1, abs(dx)]
            if dx and dy:
                v += sx * sy * q[3][abs(dy) - 1, abs(dx) - 1]
            out[7 + dy, 7 + dx] = 0.25 * v
    return out


def fast_layout(quadrants: np.ndarray) -> np.ndarray:
    """Quadrants [q][kv][kh] -> complex [kh, (z2, z1), kv] used by the fast path."""
    z1, z2 = clt.to_complex(quadrants)
    return np.stack([np.swapaxes(z2, -1, -2), np.swapaxes(z1, -1, -2)], axis=-2)


def test_complex_product_equals_reference_quadrant_product() -> None:
    rng = np.random.default_rng(0)
    a = clt.clt_tiles(rng.random((16, 16)))
    b = clt.clt_tiles(rng.random((16, 16)))
    za, zb = fast_layout(a), fast_layout(b)
    prod = np.conj(za) * zb
    ref = fast_layout(reference_product(a, b))
    assert np.allclose(prod, ref)


def test_correlation_2d_equals_reference_unfold() -> None:
    rng = np.random.default_rng(1)
    a = clt.clt_tiles(rng.random((16, 16)))
    b = clt.clt_tiles(rng.random((16, 16)))
    p = reference_product(a, b)
    ref = reference_unfold(p)
    fast = correlation.correlation_2d(
        fast_layout(p)[None, None].astype(np.complex64), lpf_sigma=0.0
    )
    # correlation_2d is scaled by 16 / sum(LPF) = 1/4 without LPF
    assert np.allclose(4.0 * fast[0, 0], ref, atol=1e-4 * np.abs(ref).max())


def test_profiles_equal_2d_correlation_along_pairs() -> None:
    rng = np.random.default_rng(2)
    p = (rng.normal(size=(3, 6, 8, 2, 8)) + 1j * rng.normal(size=(3, 6, 8, 2, 8))).astype(
        np.complex64
    )
    vectors = QuadGeometry().pair_vectors()
    lags = np.arange(-7, 8, dtype=np.float64)
    prof = correlation.profile_basis(vectors, lags, lpf_sigma=0.8)
    samples = correlation.pair_profiles(p, prof)[..., :15]
    full = correlation.correlation_2d(p, lpf_sigma=0.8)
    for i, (ex, ey) in enumerate(vectors):
        for j, d in enumerate(lags):
            dx, dy = int(d * ex), int(d * ey)
            if abs(dx) <= 7 and abs(dy) <= 7:
                assert np.allclose(samples[:, i, j], full[:, i, 7 + dy, 7 + dx], atol=1e-4)


def test_profile_derivatives_match_finite_differences() -> None:
    rng = np.random.default_rng(3)
    p = (rng.normal(size=(2, 6, 8, 2, 8)) + 1j * rng.normal(size=(2, 6, 8, 2, 8))).astype(
        np.complex64
    )
    vectors = QuadGeometry().pair_vectors()
    h = 1e-3
    lags = np.array([-1 - h, -1, -1 + h, -h, 0, h, 1 - h, 1, 1 + h])
    prof = correlation.profile_basis(vectors, lags, lpf_sigma=0.8)
    s = correlation.pair_profiles(p, prof).astype(np.float64)
    v, d1, d2 = s[..., :9], s[..., 9:12], s[..., 12:15]
    for j in range(3):
        lo, mid, hi = v[..., 3 * j], v[..., 3 * j + 1], v[..., 3 * j + 2]
        assert np.allclose(d1[..., j], (hi - lo) / (2 * h), atol=2e-2)
        assert np.allclose(d2[..., j], (hi - 2 * mid + lo) / h**2, rtol=0.05, atol=0.5)


def test_peak_at_plus_shift_of_second_image() -> None:
    """Content of b moved by +d relative to a: the correlation peak is at lag +d."""
    h = w = 64
    rng = np.random.default_rng(4)
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.fftfreq(w)[None, :]
    spec = (rng.normal(size=(h, w)) + 1j * rng.normal(size=(h, w))) * (np.hypot(fx, fy) < 0.3)
    img_a = np.fft.ifft2(spec).real
    img_b = np.fft.ifft2(spec * np.exp(-2j * np.pi * (fx * 2.0 + fy * -1.0))).real  # moved (+2, -1)
    ta = clt.clt_tiles(img_a[20:36, 20:36])
    tb = clt.clt_tiles(img_b[20:36, 20:36])
    p = fast_layout(reference_product(ta, tb))[None, None].astype(np.complex64)
    corr = correlation.correlation_2d(correlation.normalise(p, 0.0), lpf_sigma=0.8)[0, 0]
    dy, dx = np.unravel_index(np.argmax(corr), corr.shape)
    assert (dx - 7, dy - 7) == (2, -1)


def test_subpixel_gaussian_fit_is_exact_for_gaussian_peak() -> None:
    lags = np.arange(-7, 8, dtype=np.float64)
    centre = np.array([0.23, -0.41, 0.8, 3.3])
    sigma = 1.3
    dl = np.array([-1.0, 0.0, 1.0])
    val = np.exp(-((lags[None] - centre[:, None]) ** 2) / (2 * sigma**2))
    g = np.exp(-((dl[None] - centre[:, None]) ** 2) / (2 * sigma**2))
    d1 = -(dl[None] - centre[:, None]) / sigma**2 * g
    d2 = (((dl[None] - centre[:, None]) / sigma**2) ** 2 - 1 / sigma**2) * g
    prof = correlation.Profiles(lags=lags, deriv_lags=dl, basis=())
    pos, value, _ = correlation.subpixel_max(
        np.concatenate([val, d1, d2], 1).astype(np.float32), prof
    )
    assert np.allclose(pos[:3], centre[:3], atol=1e-4)  # on a derivative lag: Gaussian fit
    assert abs(pos[3] - 3.3) < 0.1  # elsewhere: parabola
    assert np.allclose(value[:3], 1.0, atol=1e-4)


def test_place_splits_integer_and_fraction() -> None:
    left, shift = place(np.array([4.0, 12.0]), np.array([1.3, -0.6]), 0.5)
    px = np.array([4.0, 12.0]) - np.array([1.3, -0.6]) * 0.5 - 8
    assert np.allclose(left - shift, px)
    assert np.all(np.abs(shift) <= 0.5)


def test_pair_products_rejects_bad_weights() -> None:
    z = np.zeros((2, 4, 3, 8, 2, 8), dtype=np.complex64)
    with pytest.raises(ValueError, match="weights shape"):
        correlation.pair_products(z, ((0, 1),), np.ones(2))
