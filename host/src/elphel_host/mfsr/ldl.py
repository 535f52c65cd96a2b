"""Batched LDL^H solve of the small Hermitian systems the Fourier solver splits into.

The forward model (:mod:`elphel_host.mfsr.forward`) decouples into one S^2 x S^2 system
``(D G D + diag(mu)) x = b`` per LR frequency; :func:`solve_blocks` solves all of them at
once, vectorised over the frequencies, and over a batch of such problems (the folds of a
cross-validation, the colour planes of a Bayer burst) that each have their own ``G``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

C64 = NDArray[np.complex64]


def solve_blocks(D: NDArray[np.float32], G: C64, mu: NDArray[np.float32], b: C64) -> C64:
    """Solve (D G D + diag(mu)) x = b for every pixel of the trailing axes (LDL^H).

    Parameters
    ----------
    D, mu
        (A, ...) real diagonal factors and prior weights.
    G
        (A, A) Hermitian, the same for every pixel; or (A, A, P, 1, ..., 1), one per
        problem of a batch of P, its trailing axes broadcasting against those of ``b``.
    b
        (A, ...) right-hand sides; with a batched ``G``, (A, P, ...).

    Returns
    -------
    x
        The solutions, shaped as ``b``.

    Notes
    -----
    The pivots d of a Hermitian matrix are real: they are kept as real arrays, which
    halves the arithmetic of every product with them.
    """
    A = G.shape[0]
    # lower triangle of M as L (unit diagonal implied) and the real pivots d
    L: list[list[C64]] = [[D[a] * D[c] * G[a, c] for c in range(a)] for a in range(A)]
    d: list[NDArray[np.float32]] = []
    for a in range(A):
        for c in range(a):
            acc = L[a][c]
            for e in range(c):
                acc = acc - (L[a][e] * d[e]) * np.conj(L[c][e])
            L[a][c] = acc / d[c]
        piv = D[a] * D[a] * np.asarray(G[a, a].real, np.float32) + mu[a]
        for e in range(a):
            z = L[a][e]
            piv = piv - d[e] * (z.real * z.real + z.imag * z.imag)
        d.append(piv)
    # forward: L y = b
    y: list[C64] = []
    for a in range(A):
        acc = b[a]
        for e in range(a):
            acc = acc - L[a][e] * y[e]
        y.append(acc)
    # diagonal and backward: L^H x = D^-1 y
    x: list[C64] = [np.zeros_like(b[0])] * A
    for a in reversed(range(A)):
        xa = y[a] / d[a]
        for e in range(a + 1, A):
            xa = xa - np.conj(L[e][a]) * x[e]
        x[a] = np.asarray(xa, dtype=np.complex64)
    return np.stack(x)
