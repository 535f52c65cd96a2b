"""The tile processor: per-tile disparity and strength of a quad image set, in passes.

A pass places every camera's tile at the current target disparity, correlates the six
pairs, and measures the residual disparity at the correlation maximum. The first pass
uses a fixed target (0 = infinity, or a coarse scan of several targets keeping the
strongest); each refinement pass re-centres every tile on the disparity measured so far,
so the final residual is small and the sub-pixel estimate works where it is most
accurate (near lag 0, where the correlation peak is symmetric).

Work is split into chunks of tiles (sized to stay in cache) processed by a few threads;
NumPy and BLAS release the GIL, and BLAS is kept single-threaded meanwhile so the
threads do not oversubscribe the cores.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from elphel_host.errors import InputFormatError
from elphel_host.parallel import parallel_map, single_threaded_blas
from elphel_host.tp.bayer import colour_weights
from elphel_host.tp.clt import tile_grid
from elphel_host.tp.correlation import (
    Profiles,
    correlation_2d,
    lpf_mask,
    normalise,
    pair_profiles,
    profile_basis,
    subpixel_max,
    window_envelope,
    windowed_centroid,
)
from elphel_host.tp.geometry import QuadGeometry, place, tile_centres
from elphel_host.tp.kernels import kernel_spectra
from elphel_host.tp.spectra import (
    CameraTransform,
    camera_spectra,
    camera_transform,
    compact_profiles,
    expand,
    padded_mosaic,
)
from elphel_host.tp.spectra import pair_products as compact_products

F32 = NDArray[np.float32]

#: DSI layers written by :func:`disparity_map`, in slice order.
DSI_LAYERS = (
    "disparity",
    "strength",
    "disparity_hor",
    "strength_hor",
    "disparity_vert",
    "strength_vert",
    "disparity_diag",
    "strength_diag",
    "disparity_cm",
    "target_disparity",
)


@dataclass(frozen=True)
class TpConfig:
    """Options of the tile processor.

    Attributes
    ----------
    fat_zero
        Absolute fat zero of the normalisation, in units of the CLT product of images
        scaled to full scale 1.0; frequencies much weaker than this are suppressed.
    lpf_sigma
        Correlation LPF (reference section 5; 0 = none).
    lpf_sigma_rb
        Extra LPF of the red and blue correlations (0 = none). Red and blue are sampled
        every second pixel, so their spectra above a quarter of the sampling rate are
        mostly alias, and an alias moves the wrong way under a phase rotation.
    green_band
        Green frequencies kept: ``kh + kv <= green_band`` (14 = all). The green
        checkerboard aliases across the anti-diagonal ``kh + kv = 7``.
    red_weight, blue_weight
        Colour weights relative to green.
    radius
        Correlation reach in pixels of residual disparity per pass.
    refine_passes
        Passes after the first, each re-centred on the disparity measured so far.
    scan
        Target disparities of the first pass; with several, each tile keeps the one whose
        correlation is strongest (for objects nearer than ``radius`` allows from 0).
    disparity_scale
        Measured residuals are divided by this (Elphel's ``corr_magic_scale``): the window
        pulls the correlation peak towards lag 0 by about 15 %.
    min_disparity
        Smallest disparity searched (a little below 0 = infinity, for calibration errors);
        keeps weak far-off noise peaks from winning against a strong near object.
    chunk_tiles
        Tiles per chunk.
    threads
        Worker threads (1 = run in the calling thread).
    pairs
        Indices into ``QuadGeometry.pairs`` used in the combined disparity.
    """

    fat_zero: float = 0.002
    lpf_sigma: float = 0.8
    lpf_sigma_rb: float = 3.0
    green_band: int = 5
    red_weight: float = 0.5
    blue_weight: float = 0.2
    radius: int = 7
    refine_passes: int = 1
    scan: tuple[float, ...] = (0.0,)
    disparity_scale: float = 0.85
    min_disparity: float = -1.0
    chunk_tiles: int = 2048
    threads: int = 2
    pairs: tuple[int, ...] = (0, 1, 2, 3, 4, 5)

    def __post_init__(self) -> None:
        checks = (
            ("fat_zero", self.fat_zero >= 0, ">= 0"),
            ("lpf_sigma", self.lpf_sigma >= 0, ">= 0"),
            ("lpf_sigma_rb", self.lpf_sigma_rb >= 0, ">= 0"),
            ("green_band", 0 <= self.green_band <= 14, "0..14"),
            ("radius", 1 <= self.radius <= 7, "1..7"),
            ("refine_passes", self.refine_passes >= 0, ">= 0"),
            ("disparity_scale", self.disparity_scale > 0, "> 0"),
            ("chunk_tiles", self.chunk_tiles >= 1, ">= 1"),
            ("threads", self.threads >= 1, ">= 1"),
            ("scan", len(self.scan) >= 1, "at least one disparity"),
            ("pairs", len(self.pairs) >= 1 and all(0 <= p < 6 for p in self.pairs), "indices 0..5"),
        )
        for name, ok, allowed in checks:
            if not ok:
                raise ValueError(f"{name}={getattr(self, name)!r}; allowed: {allowed}")


@dataclass(frozen=True)
class QuadImages:
    """Four simultaneous images of one quad, scaled to full scale 1.0.

    Attributes
    ----------
    images
        ``(4, H, W)`` float32, H and W multiples of 8 (even for Bayer).
    bayer
        Pattern name or None for mono.
    geometry
        Camera positions and pairs.
    kernels
        Optional aberration-correction kernels ``(4, colours, ky, kx, 15, 15)``
        (pixel domain, convolution): a grid at ``kernel_step`` pixels, kernel (kx, ky)
        centred at ``((kx + 0.5) * step, (ky + 0.5) * step)``; a 1 x 1 grid is one
        kernel for the whole sensor.
    kernel_step
        Grid step of ``kernels`` in pixels.
    """

    images: F32
    bayer: str | None = None
    geometry: QuadGeometry = field(default_factory=QuadGeometry)
    kernels: NDArray[np.floating] | None = None
    kernel_step: int = 16

    def __post_init__(self) -> None:
        a = self.images
        if a.ndim != 3 or a.shape[0] != 4:
            raise InputFormatError(f"images must have shape (4, H, W), got {a.shape}")
        if a.dtype != np.float32:
            raise InputFormatError(f"images must be float32, got {a.dtype}")
        tile_grid(a.shape[1], a.shape[2])
        if self.kernels is not None:
            k = self.kernels
            ncol = 1 if self.bayer is None else 3
            if k.ndim != 6 or k.shape[:2] != (4, ncol) or k.shape[4:] != (15, 15):
                raise InputFormatError(
                    f"kernels must have shape (4, {ncol}, ky, kx, 15, 15), got {k.shape}"
                )
            if self.kernel_step < 1:
                raise InputFormatError(f"kernel_step={self.kernel_step}; allowed: >= 1")

    @property
    def tiles(self) -> tuple[int, int]:
        return tile_grid(self.images.shape[1], self.images.shape[2])


@dataclass
class _Prepared:
    flats: list[F32]
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


def _prepare(quad: QuadImages, config: TpConfig, reach_px: float) -> _Prepared:
    pad = 2 * math.ceil((reach_px + 16) / 2)  # even: keeps the Bayer parity
    w = quad.images.shape[2] + 2 * pad
    transform = camera_transform(
        quad.bayer,
        colour_masks(quad.bayer, config),
        green_band=config.green_band,
        pad=pad,
        row_stride=w,
    )
    flats = [padded_mosaic(img, pad, bayer=quad.bayer is not None) for img in quad.images]
    ty, tx = quad.tiles
    lags = np.arange(-config.radius, config.radius + 1, dtype=np.float64)
    vectors = quad.geometry.pair_vectors()
    full = profile_basis(vectors, lags, lpf_sigma=config.lpf_sigma)
    return _Prepared(
        flats=flats,
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
    prep: _Prepared,
    quad: QuadImages,
    tiles: NDArray[np.intp],
    target: NDArray[np.float64],
    config: TpConfig,
) -> NDArray[np.complex64]:
    """Normalised pair products of some tiles at their targets: ``(T, pairs, 2, F)``."""
    cy = prep.centres[0].ravel()[tiles]
    cx = prep.centres[1].ravel()[tiles]
    per_camera = []
    for cam, (px, py) in enumerate(quad.geometry.positions):
        lx, sx = place(cx, target, px)
        ly, sy = place(cy, target, py)
        if prep.kernels is None:
            per_camera.append(camera_spectra(prep.flats[cam], prep.transform, lx, sx, ly, sy))
        else:
            index = _kernel_index(quad, cx - target * px, cy - target * py)
            per_camera.append(
                camera_spectra(
                    prep.flats[cam],
                    prep.transform,
                    lx,
                    sx,
                    ly,
                    sy,
                    kernels=prep.kernels[cam],
                    kernel_index=index,
                )
            )
    p = compact_products(per_camera, quad.geometry.pairs, prep.transform.fset)
    return normalise(p, config.fat_zero)


def _measure_chunk(
    prep: _Prepared,
    quad: QuadImages,
    tiles: NDArray[np.intp],
    target: NDArray[np.float64],
    config: TpConfig,
    full: bool,
) -> dict[str, F32]:
    p = _products(prep, quad, tiles, target, config)
    prof = pair_profiles(p, prep.profiles)  # (T, pairs, lags)
    groups = {"": list(config.pairs)}
    if full:
        groups.update({"_hor": [0, 1], "_vert": [2, 3], "_diag": [4, 5]})
    out: dict[str, F32] = {}
    for suffix, members in groups.items():
        combined = prof[:, members].mean(axis=1)
        nl = prep.profiles.lags.size
        levelled = (prof[:, members, :nl] / prep.envelope[members]).mean(axis=1)
        pos, val, idx = subpixel_max(
            combined, prep.profiles, lag_min=config.min_disparity - target, select=levelled
        )
        out["residual" + suffix] = pos
        out["strength" + suffix] = val
        if suffix == "":
            out["residual_cm"] = windowed_centroid(combined, prep.profiles, idx)
            out["levelled"] = levelled
    return out


def measure(
    quad: QuadImages,
    target: NDArray[np.floating],
    *,
    config: TpConfig = TpConfig(),
    prep: _Prepared | None = None,
    full: bool = True,
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
        Prepared images (internal; built when None).
    full
        False: only the combined result (the per-direction layers are NaN), as a
        first pass that only sets the next target needs.

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
    tgt = np.asarray(target, dtype=np.float64)
    if tgt.shape != (ty, tx):
        raise ValueError(f"target must have shape {(ty, tx)}, got {tgt.shape}")
    if prep is None:
        prep = _prepare(quad, config, float(np.abs(tgt).max()) + config.radius)
    flat = tgt.ravel()
    n = flat.size
    bounds = [(s, min(s + config.chunk_tiles, n)) for s in range(0, n, config.chunk_tiles)]
    keys = (
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
    nl = prep.profiles.lags.size
    result = {k: np.empty((n, nl) if k == "levelled" else n, dtype=np.float32) for k in keys}

    def run(b: tuple[int, int]) -> None:
        idx = np.arange(b[0], b[1])
        part = _measure_chunk(prep, quad, idx, flat[idx], config, full)
        for k in keys:
            result[k][b[0] : b[1]] = part.get(k, np.float32(np.nan))

    _run_chunks(run, bounds, config.threads)
    return {k: v.reshape(ty, tx, *v.shape[1:]) for k, v in result.items()}


def _run_chunks(
    fn: Callable[[tuple[int, int]], None], bounds: list[tuple[int, int]], threads: int
) -> None:
    with single_threaded_blas():
        parallel_map(fn, bounds, threads=threads)


def disparity_map(quad: QuadImages, *, config: TpConfig = TpConfig()) -> dict[str, F32]:
    """Full DSI: first pass (scan), then ``config.refine_passes`` re-centred passes.

    Returns
    -------
    dict
        One ``(tiles_y, tiles_x)`` float32 array per name in :data:`DSI_LAYERS`.
    """
    ty, tx = quad.tiles
    reach = max(abs(s) for s in config.scan) + config.radius * (config.refine_passes + 1)
    prep = _prepare(quad, config, reach)
    lags = prep.profiles.lags
    # First pass: the integer maximum is taken on the correlation summed over the 3x3
    # neighbouring tiles (surfaces are mostly smooth in depth), so a weak far peak of a
    # near object is not lost to a noise peak; the refinement then measures every tile
    # on its own data.
    target = np.zeros((ty, tx))
    scanned = np.zeros((ty, tx))
    score = np.full((ty, tx), -np.inf)
    first: dict[str, F32] | None = None
    for s in config.scan:
        tgt = np.full((ty, tx), float(s))
        m = measure(quad, tgt, config=config, prep=prep, full=config.refine_passes == 0)
        first = m
        smooth = _box3(np.where(np.isfinite(m["levelled"]), m["levelled"], 0.0))
        smooth = np.where(np.isfinite(m["levelled"]), smooth, -np.inf)
        i = np.argmax(smooth, axis=-1)
        peak = np.take_along_axis(smooth, i[..., None], -1)[..., 0]
        lo = np.take_along_axis(smooth, np.clip(i - 1, 0, lags.size - 1)[..., None], -1)[..., 0]
        hi = np.take_along_axis(smooth, np.clip(i + 1, 0, lags.size - 1)[..., None], -1)[..., 0]
        curv = lo + hi - 2 * peak
        with np.errstate(invalid="ignore", divide="ignore"):
            frac = np.where(
                np.isfinite(curv) & (curv < 0),
                0.5 * (lo - hi) / np.where(curv < 0, curv, -1.0),
                0.0,
            )
        residual = lags[i] + np.clip(frac, -0.5, 0.5)
        # where the tile's own maximum agrees with the neighbourhood, its own sub-pixel
        # estimate is the better one
        agree = np.abs(m["residual"] - residual) <= 1.0
        residual = np.where(agree, m["residual"], residual)
        estimate = tgt + residual / config.disparity_scale
        better = peak > score
        target = np.where(better, estimate, target)
        scanned = np.where(better, tgt, scanned)
        score = np.where(better, peak, score)
    assert first is not None
    if config.refine_passes == 0:
        # no refinement: report the first pass as measured at the scan target
        best = first if len(config.scan) == 1 else measure(quad, scanned, config=config, prep=prep)
        target = scanned
    for n in range(config.refine_passes):
        target = np.clip(target, config.min_disparity - 1.0, reach)
        best = measure(quad, target, config=config, prep=prep)
        if n < config.refine_passes - 1:
            target = target + best["residual"] / config.disparity_scale
    inv = 1.0 / config.disparity_scale
    out = {
        "disparity": target + inv * best["residual"],
        "strength": best["strength"],
        "disparity_hor": target + inv * best["residual_hor"],
        "strength_hor": best["strength_hor"],
        "disparity_vert": target + inv * best["residual_vert"],
        "strength_vert": best["strength_vert"],
        "disparity_diag": target + inv * best["residual_diag"],
        "strength_diag": best["strength_diag"],
        "disparity_cm": target + inv * best["residual_cm"],
        "target_disparity": target,
    }
    return {name: np.asarray(out[name], dtype=np.float32) for name in DSI_LAYERS}


def _box3(a: NDArray[np.floating]) -> NDArray[np.float64]:
    """Sum over the 3x3 neighbouring tiles (edges replicated) of a (ty, tx, ...) array."""
    p = np.pad(
        np.asarray(a, dtype=np.float64), ((1, 1), (1, 1)) + ((0, 0),) * (a.ndim - 2), mode="edge"
    )
    ty, tx = a.shape[:2]
    out = np.zeros(p[1:-1, 1:-1].shape)
    for dy in range(3):
        for dx in range(3):
            out += p[dy : dy + ty, dx : dx + tx]
    return out


def correlation_tiles(
    quad: QuadImages,
    target: NDArray[np.floating],
    *,
    config: TpConfig = TpConfig(),
    radius: int = 7,
) -> F32:
    """Pixel-domain correlation tiles of all pairs: ``(tiles_y, tiles_x, pairs, 2r+1, 2r+1)``."""
    ty, tx = quad.tiles
    tgt = np.asarray(target, dtype=np.float64)
    if tgt.shape != (ty, tx):
        raise ValueError(f"target must have shape {(ty, tx)}, got {tgt.shape}")
    prep = _prepare(quad, config, float(np.abs(tgt).max()) + config.radius)
    flat = tgt.ravel()
    n = flat.size
    npairs = len(quad.geometry.pairs)
    out = np.empty((n, npairs, 2 * radius + 1, 2 * radius + 1), dtype=np.float32)
    bounds = [(s, min(s + config.chunk_tiles, n)) for s in range(0, n, config.chunk_tiles)]

    def run(b: tuple[int, int]) -> None:
        idx = np.arange(b[0], b[1])
        p = expand(_products(prep, quad, idx, flat[idx], config), prep.transform.fset)
        out[b[0] : b[1]] = correlation_2d(p, lpf_sigma=config.lpf_sigma, radius=radius)

    _run_chunks(run, bounds, config.threads)
    return out.reshape(ty, tx, npairs, 2 * radius + 1, 2 * radius + 1)
