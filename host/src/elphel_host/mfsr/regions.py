"""A PSF per image region: the burst fused cell by cell, each with its own blur, blended.

Lenses blur more towards the corners. With a given grid of PSFs
(:class:`~elphel_host.mfsr.psf_spec.GivenGrid`, ``ky x kx`` regions) the frames are cut
into ky x kx equal cells (plus a margin of ``MARGIN`` LR px on inner sides, even-aligned
for Bayer mosaics), each cell is fused on its own with its region's PSF (its prior's tau
cross-validated on its own pixels), and the cells' outputs are blended with linear ramps
across each inner border (weights summing to 1, so a uniform scene stays uniform). The
registration is the burst's, shared by every cell.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elphel_host.mfsr.psf_spec import GivenGrid
from elphel_host.mfsr.robust_config import RobustConfig
from elphel_host.mfsr.robust_fuse import fuse_robust

F32 = NDArray[np.float32]

#: LR px each cell reaches into its neighbours: the blend's ramp is twice that wide.
MARGIN = 16
#: Smallest cell side (LR px): the blur search and the ramps need room.
MIN_CELL = 4 * MARGIN


def cell_bounds(n: int, k: int, step: int) -> list[int]:
    """``k + 1`` boundaries splitting ``n`` LR px into equal cells (multiples of ``step``)."""
    return [0, *(round(n * i / k / step) * step for i in range(1, k)), n]


def _span(bounds: list[int], i: int, n: int, scale: int) -> tuple[int, int, F32]:
    """Cell ``i``'s crop [lo, hi) in LR px (with its margins) and its blend weights (HR)."""
    lo, hi = max(bounds[i] - MARGIN, 0), min(bounds[i + 1] + MARGIN, n)
    x = np.arange((hi - lo) * scale, dtype=np.float64) + 0.5
    w = np.ones(x.size)
    m = MARGIN * scale
    if i > 0:
        w *= np.clip((x - ((bounds[i] - lo) * scale - m)) / (2 * m), 0.0, 1.0)
    if i < len(bounds) - 2:
        w *= np.clip((((bounds[i + 1] - lo) * scale + m) - x) / (2 * m), 0.0, 1.0)
    return lo, hi, np.asarray(w, dtype=np.float32)


def _check_cells(shape: tuple[int, ...], regions: tuple[int, int]) -> None:
    (h, w), (ky, kx) = shape[:2], regions
    if h < ky * MIN_CELL or w < kx * MIN_CELL:
        raise ValueError(
            f"psf regions {ky}x{kx} on {w}x{h} frames; allowed: cells of at least "
            f"{MIN_CELL} px ({w // MIN_CELL}x{h // MIN_CELL} regions at most)"
        )


def fuse_regions(
    frames: Sequence[F32],
    shifts: Sequence[tuple[float, float]],
    *,
    scale: int,
    bayer: str | None,
    grid: GivenGrid,
    config: RobustConfig,
) -> tuple[F32, dict[str, Any]]:
    """:func:`~elphel_host.mfsr.robust_fuse.fuse_robust` cell by cell with ``grid``, blended."""
    (ky, kx), (h, w), s = grid.regions, frames[0].shape, int(scale)
    _check_cells((h, w), (ky, kx))
    step = 2 if bayer is not None else 1
    by, bx = cell_bounds(h, ky, step), cell_bounds(w, kx, step)
    out: F32 | None = None
    cells: list[list[dict[str, Any]]] = [[] for _ in range(ky)]
    centre: dict[str, Any] = {}
    for iy in range(ky):
        y0, y1, wy = _span(by, iy, h, s)
        for ix in range(kx):
            x0, x1, wx = _span(bx, ix, w, s)
            crop = [np.ascontiguousarray(f[y0:y1, x0:x1]) for f in frames]
            cell = replace(config, psf=grid.cell(iy, ix))
            img, info = fuse_robust(crop, shifts, scale=s, bayer=bayer, config=cell)
            if out is None:
                out = np.zeros((h * s, w * s, *img.shape[2:]), np.float32)
            weight = wy[:, None] * wx[None, :]
            weight = weight.reshape(weight.shape + (1,) * (img.ndim - 2))
            out[y0 * s : y1 * s, x0 * s : x1 * s] += img * weight
            if (iy, ix) == (ky // 2, kx // 2):  # the shifts and noise the middle cell saw
                centre = {k: v for k, v in info.items() if k != "psf"}
            where = {"rows": [by[iy], by[iy + 1]], "columns": [bx[ix], bx[ix + 1]]}
            cells[iy].append({**where, **info.get("psf", {})})
    assert out is not None
    return out, {**centre, "psf": {"model": "regions", "regions": [ky, kx], "cells": cells}}
