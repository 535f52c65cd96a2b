"""Aberration-correction kernels in the CLT domain (Elphel's per-tile deconvolution).

A pixel-domain kernel k(dy, dx), |dy|, |dx| <= 7, becomes four 8x8 arrays so that the
element-wise "tessarine" product of a tile's CLT with them is the CLT of the tile
convolved with k: the kernel is split into its even/odd parts along each axis (odd parts
index-shifted by one), each part goes through DCT-IIIe (even axes) or DST-IIIe (odd
axes), and the result is scaled by 16 (so a unit impulse gives the identity). The
odd-odd part uses the odd-odd sign pattern: Elphel's Java uses the odd-in-x pattern
there, probably a bug, and the tests confirm that only the odd-odd pattern matches
direct convolution.

In the complex form (:mod:`elphel_host.tp.clt`) the product is simply ``z * k`` for
``z1`` and ``z2`` separately.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from elphel_host.tp.clt import N, from_complex, to_complex

FloatArray = NDArray[np.floating]

_m = np.arange(N)[None, :]
_k = np.arange(N)[:, None]
_E = np.ones(N)
_E[0] = _E[-1] = 0.5
_E_S = np.ones(N)
_E_S[-1] = 0.5
#: DCT-IIIe and DST-IIIe as Elphel defines them (non-orthogonal; e_0 = e_7 = 1/2, e'_7 = 1/2).
C3E = np.sqrt(2.0 / N) * _E[None, :] * np.cos(np.pi * _m * (2 * _k + 1) / (2 * N))
S3E = np.sqrt(2.0 / N) * _E_S[None, :] * np.sin(np.pi * (_m + 1) * (2 * _k + 1) / (2 * N))


def parity_parts(kernel: FloatArray, *, odd_odd_sign: str = "odd-odd") -> NDArray[np.float64]:
    """Even/odd parts of a 15x15 kernel: ``(4, 8, 8)`` = CC, SC, CS, SS, each [|dy|][|dx|].

    Parameters
    ----------
    kernel
        ``(15, 15)``, row = 7 + dy, column = 7 + dx.
    odd_odd_sign
        ``"odd-odd"`` (correct) or ``"odd-x"`` (the sign pattern of Elphel's Java, for
        comparison only).
    """
    k = np.asarray(kernel, dtype=np.float64)
    if k.shape != (15, 15):
        raise ValueError(f"kernel must have shape (15, 15), got {k.shape}")
    if odd_odd_sign not in ("odd-odd", "odd-x"):
        raise ValueError(f"odd_odd_sign={odd_odd_sign!r}; allowed: 'odd-odd', 'odd-x'")
    padded = np.zeros((17, 17))
    padded[1:16, 1:16] = k  # |d| up to 8 reads zeros

    def at(dy: int, dx: int) -> float:
        return float(padded[8 + dy, 8 + dx])

    out = np.zeros((4, N, N))
    for i in range(N):
        for j in range(N):
            for sy in (1, -1):
                for sx in (1, -1):
                    out[0, i, j] += at(sy * i, sx * j)
                    out[1, i, j] += sx * at(sy * i, sx * (j + 1))
                    out[2, i, j] += sy * at(sy * (i + 1), sx * j)
                    sign = sx * sy if odd_odd_sign == "odd-odd" else sx
                    out[3, i, j] += sign * at(sy * (i + 1), sx * (j + 1))
    return 0.25 * out


def kernel_clt(kernel: FloatArray, *, odd_odd_sign: str = "odd-odd") -> NDArray[np.float64]:
    """CLT-domain form ``(4, 8, 8)`` [kv][kh] of a 15x15 pixel-domain convolution kernel."""
    cc, sc, cs, ss = parity_parts(kernel, odd_odd_sign=odd_odd_sign)
    return 16.0 * np.stack([C3E @ cc @ C3E.T, C3E @ sc @ S3E.T, S3E @ cs @ C3E.T, S3E @ ss @ S3E.T])


def convolve_clt(clt: FloatArray, kernel: FloatArray) -> FloatArray:
    """Tessarine product of CLT tiles ``(..., 4, 8, 8)`` with kernel CLTs ``(..., 4, 8, 8)``."""
    t1, t2 = to_complex(np.asarray(clt))
    k1, k2 = to_complex(np.asarray(kernel))
    return from_complex(t1 * k1, t2 * k2)


def kernel_spectra(
    kernels: FloatArray, kh: NDArray[np.intp], kv: NDArray[np.intp]
) -> NDArray[np.complex64]:
    """Kernel CLTs in the fast path's compact layout: ``(..., 2, F)`` complex (z2, z1).

    Parameters
    ----------
    kernels
        ``(..., 15, 15)`` pixel-domain kernels.
    kh, kv
        The kept frequencies (``spectra.FrequencySet``).
    """
    k = np.asarray(kernels, dtype=np.float64)
    flat = k.reshape(-1, 15, 15)
    out = np.empty((flat.shape[0], 2, kh.size), dtype=np.complex64)
    for i, one in enumerate(flat):
        z1, z2 = to_complex(kernel_clt(one))
        out[i, 0] = z2[kv, kh]
        out[i, 1] = z1[kv, kh]
    return out.reshape(*k.shape[:-2], 2, kh.size)
