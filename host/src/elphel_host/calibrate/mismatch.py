"""Each tile's pair mismatch: the 2-D offset of every pair's correlation peak.

The tile processor places each camera's tile where the calibration says the tile's scene
point is, at a target disparity, and correlates the six pairs
(:mod:`elphel_host.tp.tile_pass`). Where the calibration is right and the target is the
tile's disparity, every peak lies at lag 0; a drifted camera moves the peaks of its
pairs. Here each pair's peak is found in 2-D: the integer maximum of the correlation
within ``search_px``, then Newton's method on the correlation as the continuous real
Fourier series the CLT domain gives (:mod:`elphel_host.tp.correlation`), with its exact
gradient and curvature. The peak of two tiles cut by the same window from images offset
by ``s`` lies at about ``disparity_scale * s`` (the window pulls it towards lag 0), so
the offsets are divided by that scale.

A quad's aberration kernels are not applied: the peaks are those of the tiles as
recorded. The peak lag of pair (a, b) is the offset of camera b's content relative to
camera a's: ``e_b - e_a``, with ``e_i`` where camera i sees the tile's point minus where
the tile was placed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from elphel_host.tp.clt.batch import camera_spectra, expand
from elphel_host.tp.clt.transform import OMEGA
from elphel_host.tp.config import DEFAULT_CONFIG, TpConfig
from elphel_host.tp.correlation import compact_pair_products, lpf_mask, normalise
from elphel_host.tp.images import QuadImages
from elphel_host.tp.tile_pass import PreparedQuad, prepare

F64 = NDArray[np.float64]
C128 = NDArray[np.complex128]


@dataclass(frozen=True, eq=False)
class PairOffsets:
    """The pairs' correlation peaks of every tile of one quad.

    Attributes
    ----------
    offsets_px
        ``(T, pairs, 2)``: (x, y) offset of camera b's content relative to camera a's
        for pair (a, b), in pixels (divided by the window's pull).
    strength
        ``(T, pairs)``: the correlation at the peak (1 for identical tiles).
    target
        ``(T,)``: the disparity the tiles were placed at.
    cx, cy
        ``(T,)``: the tiles' centres in the virtual camera.
    """

    offsets_px: F64
    strength: F64
    target: F64
    cx: F64
    cy: F64


def pair_offsets(
    quad: QuadImages,
    target: NDArray[np.floating],
    *,
    config: TpConfig = DEFAULT_CONFIG,
    search_px: int = 3,
) -> PairOffsets:
    """The 2-D peak of every pair of every tile, tiles placed at ``target`` (tiles_y, tiles_x).

    ``search_px``: the integer maximum is searched within this many pixels of lag 0.
    """
    if not 1 <= search_px <= 7:
        raise ValueError(f"search_px={search_px}; allowed: 1..7")
    tgt = np.asarray(target, dtype=np.float64)
    if tgt.shape != quad.tiles:
        raise ValueError(f"target must have shape {quad.tiles}, got {tgt.shape}")
    prep = prepare(quad, config, float(np.abs(tgt).max()) + search_px + 8)
    cy, cx = (c.ravel() for c in prep.centres)
    flat = tgt.ravel()
    npairs = len(quad.geometry.pairs)
    offsets = np.empty((flat.size, npairs, 2))
    strength = np.empty((flat.size, npairs))
    for start in range(0, flat.size, config.chunk_tiles):
        idx = np.arange(start, min(start + config.chunk_tiles, flat.size))
        a = _weighted_products(prep, cx[idx], cy[idx], flat[idx])
        off, val = continuous_peak(a.reshape(-1, 8, 2, 8), search_px)
        offsets[idx] = off.reshape(idx.size, npairs, 2) / config.disparity_scale
        strength[idx] = val.reshape(idx.size, npairs)
    return PairOffsets(offsets, strength, flat, cx, cy)


def _weighted_products(prep: PreparedQuad, cx: F64, cy: F64, target: F64) -> C128:
    """Normalised pair products with the correlation LPF: ``(T, pairs, 8, 2, 8)``."""
    quad, config = prep.quad, prep.config
    places = [quad.geometry.place_camera(cam, cx, cy, target) for cam in range(4)]
    spectra = [camera_spectra(quad.images[cam], prep.transform, places[cam]) for cam in range(4)]
    p = compact_pair_products(spectra, quad.geometry.pairs, prep.transform.fset)
    p = normalise(p, config.fat_zero)
    lpf = lpf_mask(config.lpf_sigma)
    weight = lpf.T[:, None, :] / (32.0 * lpf.sum() / 16.0)  # identical tiles give 1 at lag 0
    out: C128 = expand(p, prep.transform.fset).astype(np.complex128) * weight
    return out


def continuous_peak(products: C128, search_px: int, *, steps: int = 5) -> tuple[F64, F64]:
    """Peak ``(N, 2)`` (x, y lag) and value ``(N,)`` of weighted products ``(N, 8, 2, 8)``.

    ``R(dx, dy) = Re sum [z2 exp(-i(wh dx + wv dy)) + z1 exp(-i(wh dx - wv dy))]`` with
    ``z2 = products[:, kh, 0, kv]``, ``z1 = products[:, kh, 1, kv]``: its integer maximum
    within ``search_px``, then ``steps`` Newton steps (each at most 0.5 px) while the
    curvature is that of a maximum.
    """
    z2, z1 = products[:, :, 0, :], products[:, :, 1, :]
    lags = np.arange(-search_px, search_px + 1, dtype=np.float64)
    ev = np.exp(-1j * lags[:, None] * OMEGA[None, :])  # (lag, k)
    grid = ((z2 @ ev.T + z1 @ np.conj(ev).T).transpose(0, 2, 1) @ ev.T).real  # (N, dy, dx)
    best = np.argmax(grid.reshape(len(grid), -1), axis=1)
    pos = np.stack([lags[best % lags.size], lags[best // lags.size]], axis=1)
    for _ in range(steps):
        value, grad, hess = _series_derivatives(z2, z1, pos)
        det = hess[:, 0, 0] * hess[:, 1, 1] - hess[:, 0, 1] ** 2
        ok = (hess[:, 0, 0] < 0) & (det > 0)
        safe = np.where(ok, det, 1.0)
        step_x = -(hess[:, 1, 1] * grad[:, 0] - hess[:, 0, 1] * grad[:, 1]) / safe
        step_y = -(hess[:, 0, 0] * grad[:, 1] - hess[:, 0, 1] * grad[:, 0]) / safe
        step = np.where(ok[:, None], np.clip(np.stack([step_x, step_y], 1), -0.5, 0.5), 0.0)
        pos = np.clip(pos + step, -search_px - 0.5, search_px + 0.5)
    value, _, _ = _series_derivatives(z2, z1, pos)
    return pos, value


def _series_derivatives(z2: C128, z1: C128, pos: F64) -> tuple[F64, F64, F64]:
    """The series' value ``(N,)``, gradient ``(N, 2)`` and Hessian ``(N, 2, 2)`` at ``pos``."""
    eh = np.exp(-1j * pos[:, 0, None] * OMEGA[None, :])[:, :, None]  # (N, kh, 1)
    ev = np.exp(-1j * pos[:, 1, None] * OMEGA[None, :])[:, None, :]  # (N, 1, kv)
    t2 = z2 * eh * ev
    t1 = z1 * eh * np.conj(ev)
    wh, wv = OMEGA[None, :, None], OMEGA[None, None, :]
    both = t2 + t1
    diff = t2 - t1

    def total(a: C128) -> F64:
        out: F64 = a.real.sum(axis=(1, 2))
        return out

    value = total(both)
    grad = np.stack([total(-1j * wh * both), total(-1j * wv * diff)], axis=1)
    hxy = total(-wh * wv * diff)
    hess = np.stack(
        [
            np.stack([total(-wh * wh * both), hxy], axis=1),
            np.stack([hxy, total(-wv * wv * both)], axis=1),
        ],
        axis=1,
    )
    return value, grad, hess
