"""One pass of the tile processor over all tiles, at a target disparity per tile.

A pass places every camera's tile at the target disparity, transforms the four cameras
(:mod:`elphel_host.tp.clt.batch`), correlates the six pairs and measures the residual
disparity at the correlation maximum (:mod:`elphel_host.tp.correlation`). What does not
depend on the target (the transform plans, the profile basis, the kernel spectra) is
prepared once per image set and shared by every pass.

Work is split into chunks of tiles (sized to stay in cache) processed by a few threads;
NumPy and BLAS release the GIL, and BLAS is kept single-threaded meanwhile so the
threads do not oversubscribe the cores.
"""

from __future__ import annotations

import importlib
import math
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from elphel_host.parallel import parallel_map, single_threaded_blas
from elphel_host.tp.bayer import colour_weights
from elphel_host.tp.clt.batch import (
    CameraTransform,
    camera_transform,
    expand,
    raw_spectra,
    spectrum_floats,
)
from elphel_host.tp.config import DEFAULT_CONFIG, TpConfig
from elphel_host.tp.correlation import (
    Profiles,
    centroid_taper,
    compact_profiles,
    correlation_2d,
    lpf_mask,
    pair_profiles,
    profile_basis,
    window_envelope,
)
from elphel_host.tp.geometry import tile_centres
from elphel_host.tp.images import QuadImages
from elphel_host.tp.kernels import kernel_spectra

F32 = NDArray[np.float32]

#: What :func:`measure` returns, per tile.
MEASURED = (
    "residual",
    "strength",
    "residual_hor",
    "strength_hor",
    "residual_vert",
    "strength_vert",
    "residual_diag",
    "strength_diag",
    "residual_cm",
    "levelled",
)


#: The stages of a pass, as :func:`stage_times` names them.
STAGES = ("to_clt", "pair_products", "correlation", "peaks")

_stage_lock = threading.Lock()
_stage_sums: list[dict[str, float]] = []


@contextmanager
def stage_times() -> Iterator[dict[str, float]]:
    """Seconds spent in each stage of every pass run in the body (summed over threads).

    Yields a dict, filled when the body ends: per name of :data:`STAGES` the time summed
    over all chunks and threads (so with 2 threads the sum is about twice the wall time).
    ``to_clt``: placing the tiles and the four cameras' transforms; ``pair_products``:
    the six pair products and their normalisation; ``correlation``: the inverse
    transform to correlation values along each pair's disparity direction; ``peaks``:
    the means over groups of pairs, their integer maxima, sub-pixel fits and centroids.
    """
    sums = dict.fromkeys(STAGES, 0.0)
    with _stage_lock:
        _stage_sums.append(sums)
    try:
        yield sums
    finally:
        with _stage_lock:  # by identity: two collectors may hold equal sums
            del _stage_sums[next(i for i, d in enumerate(_stage_sums) if d is sums)]


def _record(name: str, t0: float) -> float:
    t1 = time.perf_counter()
    if _stage_sums:
        with _stage_lock:
            for sums in _stage_sums:
                sums[name] += t1 - t0
    return t1


def load_kernels() -> None:
    """Load the compiled per-tile kernels (:mod:`elphel_host.tp.fused`) now.

    They are imported by the first pass otherwise: importing numba and loading the
    kernels from its disk cache takes about half a CPU-second, once per process, and a
    command that times its passes loads them first.
    """
    importlib.import_module("elphel_host.tp.fused")


@dataclass(frozen=True, eq=False)
class PreparedQuad:
    """What every pass over one image set shares (see :func:`prepare`)."""

    quad: QuadImages
    config: TpConfig
    transform: CameraTransform
    centres: tuple[NDArray[np.float64], NDArray[np.float64]]
    profiles: Profiles
    pair_vectors: NDArray[np.float64]
    envelope: NDArray[np.float32]
    kernels: list[list[NDArray[np.complex64]]] | None = None


def colour_masks(bayer: str | None, config: TpConfig) -> NDArray[np.float32]:
    """Per-colour frequency weights ``(colours, 8, 2, 8)``: colour weight x colour LPF."""
    w = colour_weights(bayer, red=config.red_weight, blue=config.blue_weight)
    masks = np.ones((w.size, 8, 2, 8))
    if bayer is not None:
        rb = lpf_mask(config.lpf_sigma_rb)  # [kv][kh]
        rb = (rb / rb[0, 0]).T[:, None, :]
        masks[0] *= rb
        masks[1] *= rb
        k = np.arange(8)
        masks[2] *= ((k[:, None] + k[None, :]) <= config.green_band)[:, None, :]
    out: NDArray[np.float32] = (w[:, None, None, None] * masks).astype(np.float32)
    return out


def prepare(quad: QuadImages, config: TpConfig, reach_px: float) -> PreparedQuad:
    """Prepare an image set for passes whose tiles move at most ``reach_px`` pixels."""
    pad = 2 * math.ceil((reach_px + 16) / 2)  # even: keeps the Bayer parity
    transform = camera_transform(
        quad.bayer,
        colour_masks(quad.bayer, config),
        green_band=config.green_band,
        pad=pad,
    )
    ty, tx = quad.tiles
    lags = np.arange(-config.radius, config.radius + 1, dtype=np.float64)
    vectors = quad.geometry.pair_vectors()
    full = profile_basis(vectors, lags, lpf_sigma=config.lpf_sigma)
    return PreparedQuad(
        quad=quad,
        config=config,
        transform=transform,
        centres=tile_centres(ty, tx),
        profiles=compact_profiles(full, transform.fset, lpf_mask(config.lpf_sigma)),
        pair_vectors=vectors,
        envelope=np.maximum(window_envelope(lags, vectors), 0.05).astype(np.float32),
        kernels=None
        if quad.kernels is None
        else [
            [
                kernel_spectra(
                    quad.kernels[cam, c].reshape(-1, 15, 15), transform.fset.kh, transform.fset.kv
                )
                for c in range(quad.kernels.shape[1])
            ]
            for cam in range(4)
        ],
    )


def _kernel_index(
    quad: QuadImages, cx: NDArray[np.float64], cy: NDArray[np.float64]
) -> NDArray[np.intp]:
    """Nearest kernel of the grid to each tile centre on the sensor."""
    assert quad.kernels is not None
    ky, kx = quad.kernels.shape[2:4]
    step = quad.kernel_step
    ix = np.clip(np.floor(cx / step).astype(np.intp), 0, kx - 1)
    iy = np.clip(np.floor(cy / step).astype(np.intp), 0, ky - 1)
    out: NDArray[np.intp] = iy * kx + ix
    return out


def _products(
    prep: PreparedQuad,
    tiles: NDArray[np.intp],
    target: NDArray[np.float64],
    t0: float | None = None,
) -> F32:
    """Normalised pair products of some tiles at their targets: ``(T, pairs, 2, 2, F)``.

    Planar: (which, re/im, f) per tile and pair (the rows of :attr:`PreparedQuad.profiles`).
    """
    from elphel_host.tp.fused import rotated_pair_products  # see load_kernels

    quad = prep.quad
    tr = prep.transform
    cy = prep.centres[0].ravel()[tiles]
    cx = prep.centres[1].ravel()[tiles]
    t = tiles.size
    spectra = np.empty((4, t, spectrum_floats(tr)), dtype=np.float32)
    shifts = np.empty((4, t, 2), dtype=np.float32)
    for cam, (px, py) in enumerate(quad.geometry.positions):
        at = quad.geometry.place_camera(cam, cx, cy, target)
        kernels, index = None, None
        if prep.kernels is not None:
            kernels = prep.kernels[cam]
            index = _kernel_index(quad, cx - target * px, cy - target * py)
        shifts[cam] = raw_spectra(
            quad.images[cam], tr, at, spectra[cam], kernels=kernels, kernel_index=index
        )
    if t0 is not None:
        t0 = _record("to_clt", t0)
    pairs = np.array(quad.geometry.pairs, dtype=np.int64)
    fset = tr.fset
    # pair-major, so each pair's products are one contiguous block (returned transposed)
    out = np.empty((len(pairs), t, 2, 2, fset.size), dtype=np.float32)
    angle = (np.pi / 16) * shifts
    rotation = np.stack([np.cos(angle), np.sin(angle)], axis=-1)  # (cameras, T, x/y, cos/sin)
    rotated_pair_products(
        spectra,
        rotation,
        pairs,
        fset.kh.astype(np.int64),
        fset.kv.astype(np.int64),
        np.array(tr.colour_sizes, dtype=np.int64),
        np.float32(prep.config.fat_zero),
        out,
    )
    if t0 is not None:
        _record("pair_products", t0)
    p: F32 = out.transpose(1, 0, 2, 3, 4)
    return p


def _group_means(config: TpConfig, npairs: int, full: bool) -> F32:
    """``(groups, pairs)``: each group's mean over its pairs (the rows of :data:`_GROUPS`).

    The groups: the pairs of ``config.pairs``, then (when ``full``) the horizontal,
    vertical and diagonal pairs.
    """
    members = [list(config.pairs), [0, 1], [2, 3], [4, 5]][: len(_GROUPS) if full else 1]
    means = np.zeros((len(members), npairs), dtype=np.float32)
    for g, m in enumerate(members):
        means[g, m] = 1.0 / len(m)
    return means


#: The suffixes of :data:`MEASURED` of each group of pairs (:func:`_group_means`).
_GROUPS = ("", "_hor", "_vert", "_diag")


def _measure_chunk(
    prep: PreparedQuad, tiles: NDArray[np.intp], target: NDArray[np.float64], full: bool
) -> dict[str, F32]:
    from elphel_host.tp.fused import correlation_peaks  # see load_kernels

    t0 = time.perf_counter()
    p = _products(prep, tiles, target, t0)
    t0 = time.perf_counter()
    prof = pair_profiles(p, prep.profiles)  # (T, pairs, samples)
    t0 = _record("correlation", t0)
    means = _group_means(prep.config, prof.shape[1], full)
    n, nl = tiles.size, prep.profiles.lags.size
    residual = np.empty((n, means.shape[0]), dtype=np.float32)
    strength = np.empty_like(residual)
    out = {"residual_cm": np.empty(n, dtype=np.float32), "levelled": np.empty((n, nl), np.float32)}
    correlation_peaks(
        prof,
        means,
        prep.envelope,
        prep.profiles.lags,
        prep.profiles.deriv_lags,
        centroid_taper(),
        prep.config.min_disparity - target,
        residual,
        strength,
        out["residual_cm"],
        out["levelled"],
    )
    for g in range(means.shape[0]):
        out["residual" + _GROUPS[g]] = residual[:, g]
        out["strength" + _GROUPS[g]] = strength[:, g]
    _record("peaks", t0)
    return out


def _checked_target(quad: QuadImages, target: NDArray[np.floating]) -> NDArray[np.float64]:
    tgt = np.asarray(target, dtype=np.float64)
    if tgt.shape != quad.tiles:
        raise ValueError(f"target must have shape {quad.tiles}, got {tgt.shape}")
    return tgt


#: The number of chunks of a pass is a multiple of this (see `_in_chunks`).
CHUNK_GROUP = 4


def _in_chunks(fn: Callable[[NDArray[np.intp]], None], n: int, config: TpConfig) -> None:
    """``fn(tile indices)`` over chunks of at most ``config.chunk_tiles`` on ``config.threads``.

    The chunks are of equal size and a multiple of `CHUNK_GROUP` in number, so that no
    thread of 1, 2 or 4 is left alone with the last chunk. Their sizes do not depend on
    the thread count, so neither does the DSI (a matrix product of another size may round
    differently).
    """
    count = CHUNK_GROUP * -(-n // (CHUNK_GROUP * config.chunk_tiles))
    size = -(-n // count)
    bounds = [(s, min(s + size, n)) for s in range(0, n, size)]
    with single_threaded_blas():
        parallel_map(lambda b: fn(np.arange(b[0], b[1])), bounds, threads=config.threads)


def measure(
    quad: QuadImages,
    target: NDArray[np.floating],
    *,
    config: TpConfig = DEFAULT_CONFIG,
    prep: PreparedQuad | None = None,
    full: bool = True,
    step: int = 1,
) -> dict[str, F32]:
    """One pass: residual disparities and strengths of all tiles at a target disparity.

    Parameters
    ----------
    quad
        The images.
    target
        ``(tiles_y, tiles_x)`` target disparity per tile.
    config
        Options.
    prep
        :func:`prepare` of ``quad`` and ``config`` (built when None).
    full
        False: only the combined result (the per-direction layers are NaN), as a
        first pass that only sets the next target needs.
    step
        Measure only the tiles ``(step * i, step * j)``; the arrays are then those of
        that coarser grid, ``(ceil(tiles_y / step), ceil(tiles_x / step))``.

    Returns
    -------
    dict
        ``residual``, ``strength`` and the same with suffixes ``_hor``, ``_vert``,
        ``_diag``, plus ``residual_cm`` (windowed centroid), each ``(tiles_y, tiles_x)``,
        and ``levelled``: ``(tiles_y, tiles_x, lags)`` combined correlation divided by the
        window-overlap envelope (lags below ``min_disparity`` at -inf).
        The disparity is ``target + residual``.
    """
    ty, tx = quad.tiles
    tgt = _checked_target(quad, target)
    if step < 1:
        raise ValueError(f"step={step}; allowed: >= 1")
    if prep is None:
        prep = prepare(quad, config, float(np.abs(tgt).max()) + config.radius)
    rows, cols = np.arange(0, ty, step), np.arange(0, tx, step)
    tiles = (rows[:, None] * tx + cols[None, :]).ravel()
    flat = tgt.ravel()
    n = tiles.size
    nl = prep.profiles.lags.size
    result = {k: np.empty((n, nl) if k == "levelled" else n, dtype=np.float32) for k in MEASURED}

    def run(idx: NDArray[np.intp]) -> None:
        part = _measure_chunk(prep, tiles[idx], flat[tiles[idx]], full)
        for k in MEASURED:
            result[k][idx[0] : idx[-1] + 1] = part.get(k, np.float32(np.nan))

    _in_chunks(run, n, prep.config)
    return {k: v.reshape(rows.size, cols.size, *v.shape[1:]) for k, v in result.items()}


def correlation_tiles(
    quad: QuadImages,
    target: NDArray[np.floating],
    *,
    config: TpConfig = DEFAULT_CONFIG,
    radius: int = 7,
) -> F32:
    """Pixel-domain correlation tiles of all pairs: ``(tiles_y, tiles_x, pairs, 2r+1, 2r+1)``."""
    ty, tx = quad.tiles
    tgt = _checked_target(quad, target)
    prep = prepare(quad, config, float(np.abs(tgt).max()) + config.radius)
    flat = tgt.ravel()
    n = flat.size
    npairs = len(quad.geometry.pairs)
    out = np.empty((n, npairs, 2 * radius + 1, 2 * radius + 1), dtype=np.float32)

    def run(idx: NDArray[np.intp]) -> None:
        planar = _products(prep, idx, flat[idx])
        p = expand(planar[:, :, :, 0] + 1j * planar[:, :, :, 1], prep.transform.fset)
        out[idx[0] : idx[-1] + 1] = correlation_2d(p, lpf_sigma=config.lpf_sigma, radius=radius)

    _in_chunks(run, n, config)
    return out.reshape(ty, tx, npairs, 2 * radius + 1, 2 * radius + 1)
