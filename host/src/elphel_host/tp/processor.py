"""The tile processor: per-tile disparity and strength of a quad image set, in passes.

A pass (:mod:`elphel_host.tp.tile_pass`) places every camera's tile at the current target
disparity, correlates the six pairs, and measures the residual disparity at the
correlation maximum. The first pass uses a fixed target (0 = infinity, or a coarse scan
of several targets keeping the strongest); each refinement pass re-centres every tile on
the disparity measured so far, so the final residual is small and the sub-pixel
estimate works where it is most accurate (near lag 0, where the correlation peak is
symmetric). A calibrated quad's cameras move by other than one pixel per unit of
disparity (:meth:`~elphel_host.tp.geometry.QuadGeometry.disparity_gain`): its measured
residuals are divided by that gain too.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from elphel_host.tp.config import DEFAULT_CONFIG, TpConfig
from elphel_host.tp.images import QuadImages
from elphel_host.tp.tile_pass import measure, prepare

__all__ = ["DSI_LAYERS", "disparity_map"]

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


def disparity_map(quad: QuadImages, *, config: TpConfig = DEFAULT_CONFIG) -> dict[str, F32]:
    """Full DSI: first pass (scan), then ``config.refine_passes`` re-centred passes.

    Returns
    -------
    dict
        One ``(tiles_y, tiles_x)`` float32 array per name in :data:`DSI_LAYERS`.
    """
    ty, tx = quad.tiles
    reach = max(abs(s) for s in config.scan) + config.radius * (config.refine_passes + 1)
    prep = prepare(quad, config, reach)
    # raw pixels of residual per unit of disparity (1 for the ideal square)
    scale = config.disparity_scale * quad.geometry.disparity_gain(prep.centres[1], prep.centres[0])
    # First pass: at each scan target, keep per tile the target whose neighbourhood
    # correlates best; the refinement then measures every tile on its own data.
    target = np.zeros((ty, tx))
    scanned = np.zeros((ty, tx))
    score = np.full((ty, tx), -np.inf)
    first: dict[str, F32] | None = None
    # with a refinement to follow, the first pass needs only a coarse grid of tiles
    step = config.first_pass_step if config.refine_passes else 1
    for s in config.scan:
        tgt = np.full((ty, tx), float(s))
        m = measure(quad, tgt, config=config, prep=prep, full=config.refine_passes == 0, step=step)
        first = m
        if step > 1:
            m = {k: _nearest_measured(m[k], step, (ty, tx)) for k in ("levelled", "residual")}
        residual, peak = _neighbourhood_peak(m, prep.profiles.lags)
        estimate = tgt + residual / scale
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
            target = target + best["residual"] / scale
    inv = 1.0 / scale
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


def _neighbourhood_peak(
    measured: dict[str, F32], lags: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """First-pass residual and peak value per tile, from the 3x3 neighbourhood's correlation.

    The integer maximum is taken on the levelled correlation summed over the 3x3
    neighbouring tiles (surfaces are mostly smooth in depth), so a weak far peak of a near
    object is not lost to a noise peak; a parabola through it and its neighbours gives the
    fraction. Where the tile's own maximum agrees with the neighbourhood (within 1 px),
    its own sub-pixel estimate is the better one. One compiled loop
    (:func:`elphel_host.tp.fused.neighbourhood_peaks`).
    """
    from elphel_host.tp.fused import neighbourhood_peaks  # see tile_pass.load_kernels

    levelled = np.ascontiguousarray(measured["levelled"], dtype=np.float32)
    if levelled.shape[2] > 64:  # the kernel's scratch
        raise ValueError(f"{levelled.shape[2]} lags; allowed: at most 64")
    residual = np.empty(levelled.shape[:2])
    peak = np.empty(levelled.shape[:2])
    own = np.ascontiguousarray(measured["residual"], dtype=np.float32)
    neighbourhood_peaks(levelled, own, np.asarray(lags, dtype=np.float64), residual, peak)
    return residual, peak


def _nearest_measured(a: F32, step: int, shape: tuple[int, int]) -> F32:
    """Values of the tiles ``(step * i, step * j)`` spread to the whole grid ``shape``."""
    out: F32 = np.repeat(np.repeat(a, step, axis=0), step, axis=1)[: shape[0], : shape[1]]
    return out
