"""A PSF per image region: the burst fused cell by cell, each with its own blur, blended.

Lenses blur more towards the corners. With ``RobustConfig.psf_regions = (ky, kx)`` the
frames are cut into ky x kx equal cells (plus a margin of ``MARGIN`` LR px on inner
sides, even-aligned for Bayer mosaics), each cell is fused on its own — its blur
estimated from its own pixels, or taken from a given kernel grid (``psf_grid``, one PSF
per cell) — and the cells' outputs are blended with linear ramps across each inner
border (weights summing to 1, so a uniform scene stays uniform). The registration is the
burst's, shared by every cell.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elphel_host.mfsr.registration import FrameRegistration
from elphel_host.mfsr.robust_config import RobustConfig

F32 = NDArray[np.float32]

#: LR px each cell reaches into its neighbours: the blend's ramp is twice that wide.
MARGIN = 16
#: Smallest cell side (LR px): the blur search and the ramps need room.
MIN_CELL = 4 * MARGIN


def cell_bounds(n: int, k: int, step: int) -> list[int]:
    """``k + 1`` boundaries splitting ``n`` LR px into equal cells (multiples of ``step``)."""
    return [0, *(round(n * i / k / step) * step for i in range(1, k)), n]


def _ramp(n: int, lo: int, hi: int, margin: int, first: bool, last: bool) -> F32:
    """Weights over ``n`` samples of a crop for the cell [lo, hi) (crop coordinates)."""
    x = np.arange(n, dtype=np.float64) + 0.5
    w = np.ones(n)
    if not first:
        w *= np.clip((x - (lo - margin)) / (2 * margin), 0.0, 1.0)
    if not last:
        w *= np.clip(((hi + margin) - x) / (2 * margin), 0.0, 1.0)
    return np.asarray(w, dtype=np.float32)


def cell_config(config: RobustConfig, iy: int, ix: int) -> RobustConfig:
    """The options one cell is fused with: its kernel from the grid, else an estimate.

    A cell with its kernel still gets its own prior's tau searched (``estimate_psf``).
    """
    if config.psf_grid is None:
        return replace(config, psf_regions=(1, 1), psf_frame=None)
    return replace(
        config,
        psf_regions=(1, 1),
        psf_grid=None,
        psf_frame=None,
        psf_kernel=config.psf_grid[iy, ix],
        psf_rgb=None if config.psf_rgb is None else config.psf_rgb[:, iy, ix],
    )


def fuse_regions(
    frames: Sequence[F32],
    regs: Sequence[FrameRegistration],
    *,
    scale: int,
    bayer: str | None,
    config: RobustConfig,
) -> tuple[F32, dict[str, Any]]:
    """`fuse_registered` (robust) cell by cell with ``config.psf_regions``, blended."""
    from elphel_host.mfsr.fuse import fuse_registered

    ky, kx = config.psf_regions
    h, w = frames[0].shape
    if h < ky * MIN_CELL or w < kx * MIN_CELL:
        raise ValueError(
            f"psf regions {ky}x{kx} on {w}x{h} frames; allowed: cells of at least "
            f"{MIN_CELL} px ({w // MIN_CELL}x{h // MIN_CELL} regions at most)"
        )
    step = 2 if bayer is not None else 1
    by, bx = cell_bounds(h, ky, step), cell_bounds(w, kx, step)
    m, s = MARGIN, int(scale)
    out: F32 | None = None
    cells: list[list[dict[str, Any]]] = []
    centre: dict[str, Any] = {}
    for iy in range(ky):
        row = []
        y0, y1 = max(by[iy] - m, 0), min(by[iy + 1] + m, h)
        wy = _ramp((y1 - y0) * s, (by[iy] - y0) * s, (by[iy + 1] - y0) * s, m * s,
                   iy == 0, iy == ky - 1)  # fmt: skip
        for ix in range(kx):
            x0, x1 = max(bx[ix] - m, 0), min(bx[ix + 1] + m, w)
            wx = _ramp((x1 - x0) * s, (bx[ix] - x0) * s, (bx[ix + 1] - x0) * s, m * s,
                       ix == 0, ix == kx - 1)  # fmt: skip
            crop = [np.ascontiguousarray(f[y0:y1, x0:x1]) for f in frames]
            img, info = fuse_registered(
                crop,
                regs,
                scale=s,
                method="robust",
                bayer=bayer,
                config=cell_config(config, iy, ix),
            )
            if out is None:
                out = np.zeros((h * s, w * s, *img.shape[2:]), np.float32)
            weight = wy[:, None] * wx[None, :]
            out[y0 * s : y1 * s, x0 * s : x1 * s] += img * weight.reshape(
                weight.shape + (1,) * (img.ndim - 2)
            )
            if (iy, ix) == (ky // 2, kx // 2):  # the shifts and noise the middle cell saw
                centre = {k: v for k, v in info.items() if k != "psf"}
            row.append(
                {
                    "rows": [by[iy], by[iy + 1]],
                    "columns": [bx[ix], bx[ix + 1]],
                    **info.get("psf", {}),
                }
            )
        cells.append(row)
    assert out is not None
    return out, {**centre, "psf": {"model": "regions", "regions": [ky, kx], "cells": cells}}
