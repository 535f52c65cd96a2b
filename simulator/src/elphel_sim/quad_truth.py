"""The true disparity of every tile of a quad scene, ray-cast from the virtual centre camera.

Tile (tx, ty) of the tile processor has its centre at (8tx+4, 8ty+4); `tile_truth` casts
that pixel's ray into the scene's planes, gives the disparity of what it meets, and marks
the tiles whose footprint (plus the disparity shift) lies within one region in every
camera: the ones whose disparity is defined without a depth edge.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from elphel_sim.quad import QuadRig, QuadScene, Region


@dataclass(frozen=True)
class TileTruth:
    """True disparity of every tile centre of the virtual centre camera.

    Attributes
    ----------
    disparity
        ``(tiles_y, tiles_x)`` float64.
    label
        Index into ``names`` of the region seen at each tile centre (-1: nothing).
    names
        Region names.
    interior
        Tiles whose 16x16 footprint (plus the disparity shift) lies within one region in
        every camera: the ones whose disparity is defined without a depth edge.
    textured
        Whether each tile's region is textured.
    """

    disparity: NDArray[np.float64]
    label: NDArray[np.intp]
    names: tuple[str, ...]
    interior: NDArray[np.bool_]
    textured: NDArray[np.bool_]


def _cast(
    rig: QuadRig, scene: QuadScene, xs: NDArray[np.float64], ys: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """Depth and region label seen by the centre camera at continuous pixel coordinates."""
    cx, cy = rig.intrinsics.principal_point
    d = np.stack(
        [
            (xs - cx) * rig.pitch_mm,
            (ys - cy) * rig.pitch_mm,
            np.full(xs.shape, rig.focal_length_mm),
        ],
        -1,
    )
    best, label = nearest_hits(scene.regions, d)
    depth = best * rig.focal_length_mm
    return depth, label


def nearest_hits(
    regions: Sequence[Region],
    d: NDArray[np.float64],
    origin_mm: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """The nearest region each ray ``origin + t * d`` meets: ``t`` (inf if none) and its index.

    ``d`` is (..., 3); a region is its plane, bounded by its half extents where it has them.
    """
    o0 = np.zeros(3) if origin_mm is None else np.asarray(origin_mm, dtype=np.float64)
    best = np.full(d.shape[:-1], np.inf)
    label = np.full(d.shape[:-1], -1, dtype=np.intp)
    for i, region in enumerate(regions):
        u, v, nrm = region.plane.basis()
        o = np.asarray(region.plane.origin, dtype=np.float64) - o0
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (nrm @ o) / (d @ nrm)
        hit = t[..., None] * d
        ok = np.isfinite(t) & (t > 0) & (t < best)
        if region.plane.half_extent_mm is not None:
            hu, hv = region.plane.half_extent_mm
            ok &= (np.abs((hit - o) @ u) <= hu) & (np.abs((hit - o) @ v) <= hv)
        best = np.where(ok, t, best)
        label = np.where(ok, i, label)
    return best, label


def tile_truth(scene: QuadScene, *, margin_px: float = 12.0) -> TileTruth:
    """True per-tile disparity at tile centres (8tx+4, 8ty+4) of the virtual centre camera."""
    rig = scene.rig
    ty, tx = rig.height // 8, rig.width // 8
    yy, xx = np.meshgrid(8.0 * np.arange(ty) + 4.0, 8.0 * np.arange(tx) + 4.0, indexing="ij")
    depth, label = _cast(rig, scene, xx, yy)
    disparity = np.where(
        np.isfinite(depth), rig.disparity_px(np.where(np.isfinite(depth), depth, 1.0)), 0.0
    )
    # interior: same label on a ring of probes around the tile centre (tile half-size plus
    # the largest camera offset) in the centre view
    reach = margin_px + 0.5 * float(np.max(disparity)) * np.sqrt(2.0)
    interior = label >= 0
    for ang in np.linspace(0, 2 * np.pi, 16, endpoint=False):
        for r in (0.5 * reach, reach):
            _, lab = _cast(rig, scene, xx + r * np.cos(ang), yy + r * np.sin(ang))
            interior &= lab == label
    textured = np.array([r.textured for r in scene.regions])[np.maximum(label, 0)] & (label >= 0)
    return TileTruth(disparity, label, tuple(r.name for r in scene.regions), interior, textured)
