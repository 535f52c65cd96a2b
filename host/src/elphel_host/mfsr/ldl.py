"""Batched LDL^H solve of the small Hermitian systems the Fourier solver splits into.

The forward model (:mod:`elphel_host.mfsr.forward`) decouples into one S^2 x S^2 system
``(D G D + w diag(L)) x = c D r`` per LR frequency; :func:`solve_blocks` solves all of them at
once, over the frequencies, and over a batch of such problems (the folds of a
cross-validation, the colour planes of a Bayer burst) that each have their own ``G``.

The factorization is one compiled kernel (numba, host only): a block of frequencies at a
time, real and imaginary parts in separate arrays, so that every step of the LDL^H is a
short loop over the block that the compiler turns into vector instructions. NumPy would
make one pass over memory per element-wise step; S^2 = 16 (a Bayer plane at x2) takes
S^6 / 6 such steps per solve.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from numpy.typing import NDArray

C64 = NDArray[np.complex64]
F32 = NDArray[np.float32]

# frequencies a step of the kernel takes at once: its factors stay in the core's cache
_BLOCK = 64

_F32_IN = nb.types.Array(nb.float32, 2, "A", readonly=True)
_KERNEL_SIGNATURE = nb.void(
    _F32_IN,  # D (A, N)
    _F32_IN,  # prior L (A, N)
    nb.float32,  # the prior's weight w
    nb.float32,  # the right-hand side's scale c
    _F32_IN,  # Re G (A, A)
    _F32_IN,  # Im G
    nb.types.Array(nb.complex64, 2, "A", readonly=True),  # b (A, N)
    nb.complex64[:, :],  # x (A, N), out
)


@nb.njit(inline="always", cache=True, nogil=True, fastmath=True, boundscheck=False)
def _load(
    D: F32, prior: F32, w: np.float32, gr: F32, gi: F32, p0: int, m: int, lr: F32, li: F32
) -> None:
    """The lower triangle of the block's matrices, row-major, into ``lr``, ``li``."""
    for a in range(D.shape[0]):
        for c in range(a + 1):
            t = a * (a + 1) // 2 + c
            for j in range(m):
                dd = D[a, p0 + j] * D[c, p0 + j]
                lr[t, j] = dd * gr[a, c]
                li[t, j] = dd * gi[a, c]
        t = a * (a + 1) // 2 + a
        for j in range(m):
            lr[t, j] += w * prior[a, p0 + j]


@nb.njit(inline="always", cache=True, nogil=True, fastmath=True, boundscheck=False)
def _factor(A: int, m: int, lr: F32, li: F32, inv_d: F32) -> None:
    """LDL^H in place, row by row: L below the diagonal, 1 / d in ``inv_d``."""
    for a in range(A):
        ra = a * (a + 1) // 2
        for c in range(a):  # row a's (L d) first
            rc = c * (c + 1) // 2
            for e in range(c):
                for j in range(m):
                    # (L d)[a,c] -= (L d)[a,e] conj(L[c,e])
                    pr, pi = lr[ra + e, j], li[ra + e, j]
                    qr, qi = lr[rc + e, j], li[rc + e, j]
                    lr[ra + c, j] -= pr * qr + pi * qi
                    li[ra + c, j] -= pi * qr - pr * qi
        for j in range(m):
            piv = lr[ra + a, j]
            for e in range(a):  # d[a] = M[a,a] - sum |(L d)[a,e]|^2 / d[e]
                pr, pi = lr[ra + e, j], li[ra + e, j]
                piv -= (pr * pr + pi * pi) * inv_d[e, j]
            inv_d[a, j] = 1.0 / piv
        for e in range(a):  # then its L
            for j in range(m):
                lr[ra + e, j] *= inv_d[e, j]
                li[ra + e, j] *= inv_d[e, j]


@nb.njit(inline="always", cache=True, nogil=True, fastmath=True, boundscheck=False)
def _substitute(m: int, lr: F32, li: F32, inv_d: F32, yr: F32, yi: F32) -> None:
    """(y_r + i y_i) overwritten by (L D L^H)^-1 of itself: forward, diagonal, backward."""
    A = yr.shape[0]
    for a in range(A):  # L y = b
        ra = a * (a + 1) // 2
        for e in range(a):
            for j in range(m):
                pr, pi = lr[ra + e, j], li[ra + e, j]
                yr[a, j] -= pr * yr[e, j] - pi * yi[e, j]
                yi[a, j] -= pr * yi[e, j] + pi * yr[e, j]
    for a in range(A - 1, -1, -1):  # L^H x = D^-1 y
        for j in range(m):
            yr[a, j] *= inv_d[a, j]
            yi[a, j] *= inv_d[a, j]
        for e in range(a + 1, A):
            re = e * (e + 1) // 2
            for j in range(m):
                # x[a] -= conj(L[e,a]) x[e]
                pr, pi = lr[re + a, j], li[re + a, j]
                yr[a, j] -= pr * yr[e, j] + pi * yi[e, j]
                yi[a, j] -= pr * yi[e, j] - pi * yr[e, j]


@nb.njit(_KERNEL_SIGNATURE, cache=True, nogil=True, fastmath=True, boundscheck=False)
def _ldl_kernel(
    D: F32, prior: F32, w: np.float32, c: np.float32, gr: F32, gi: F32, r: C64, x: C64
) -> None:
    """Solve (D G D + w diag(L)) x = c D r for every column (N frequencies) of D, L, r."""
    A, n = D.shape
    lr = np.empty((A * (A + 1) // 2, _BLOCK), np.float32)
    li = np.empty_like(lr)
    inv_d = np.empty((A, _BLOCK), np.float32)
    yr = np.empty((A, _BLOCK), np.float32)
    yi = np.empty_like(yr)
    for p0 in range(0, n, _BLOCK):
        m = min(_BLOCK, n - p0)
        _load(D, prior, w, gr, gi, p0, m, lr, li)
        _factor(A, m, lr, li, inv_d)
        for a in range(A):
            for j in range(m):
                cd = c * D[a, p0 + j]
                yr[a, j] = cd * r[a, p0 + j].real
                yi[a, j] = cd * r[a, p0 + j].imag
        _substitute(m, lr, li, inv_d, yr, yi)
        for a in range(A):
            for j in range(m):
                x[a, p0 + j] = complex(yr[a, j], yi[a, j])


def solve_blocks(
    D: F32,
    G: C64,
    prior: F32,
    r: C64,
    *,
    weight: F32 | float,
    scale: float = 1.0,
    out: C64 | None = None,
) -> C64:
    """Solve (D G D + w diag(L)) x = c D r for every pixel of the trailing axes (LDL^H).

    Parameters
    ----------
    D, prior
        (A, ...) real diagonal factors and the prior's shape L; with a batched ``G``,
        (A, P or 1, ...).
    G
        (A, A) Hermitian, the same for every pixel; or (A, A, P, 1, ..., 1), one per
        problem of a batch of P.
    r
        (A, ...) right-hand sides before their factor ``c D``; with a batched ``G``,
        (A, P, ...).
    weight
        The prior's weight w: one, or (P,) one per problem.
    scale
        The right-hand side's factor c.
    out
        Where to write the solutions (complex64, shaped as ``r``, each problem's trailing
        axes contiguous); default a new array.

    Returns
    -------
    x
        The solutions (complex64), shaped as ``r``: ``out`` when given.

    Notes
    -----
    The pivots d of a Hermitian matrix are real: the kernel keeps them as real arrays,
    which halves the arithmetic of every product with them.
    """
    if G.ndim == 2:
        dest = None if out is None else out[:, None]
        batch = (D[:, None], G[:, :, None], prior[:, None], r[:, None])
        return solve_blocks(*batch, weight=weight, scale=scale, out=dest)[:, 0]
    A, P = G.shape[0], G.shape[2]
    if r.shape[:2] != (A, P):
        raise ValueError(f"r of shape {r.shape}; allowed: ({A}, {P}, ...) for G of {G.shape}")
    w = np.broadcast_to(np.asarray(weight, np.float32), (P,))
    n = int(np.prod(r.shape[2:]))
    if out is None:
        out = np.empty(r.shape, np.complex64)
    elif out.shape != r.shape or out.dtype != np.complex64:
        raise ValueError(f"out {out.dtype} {out.shape}; allowed: complex64 {r.shape}")
    for p in range(P):
        g = np.asarray(G[:, :, p], np.complex64).reshape(A, A)
        _ldl_kernel(
            _columns(D, p, n),
            _columns(prior, p, n),
            np.float32(w[p]),
            np.float32(scale),
            np.ascontiguousarray(g.real),
            np.ascontiguousarray(g.imag),
            np.asarray(r[:, p], np.complex64).reshape(A, n),
            np.reshape(out[:, p], (A, n), copy=False),
        )
    return out


def _columns(v: F32, p: int, n: int) -> F32:
    """Problem p's (A, n) float32 view of ``v`` (A, P or 1, ...); a copy only if needed."""
    part = np.asarray(v[:, p if v.shape[1] > 1 else 0], np.float32)
    return part.reshape(part.shape[0], n)
