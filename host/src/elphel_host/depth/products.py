"""A quad's DSI as depth: the depth map (mm), the point cloud and their pictures.

Tiles whose strength is below the threshold are left out (NaN in the depth map, no
point) and counted, and so are tiles at or beyond infinity (disparity <= 0) and tiles
whose directions disagree: the combined disparity more than ``max_disagreement`` (a
fraction, 0.25 by default) and more than 0.25 px away from the median of the horizontal,
vertical and diagonal disparities that pass the strength threshold themselves. Depth is
inverse to disparity, so that is a tile whose depth the pair directions do not agree on
within about that fraction; a tile without a confident direction is kept. Each point's
colour is the mean of what the four cameras see where the measured disparity puts the
tile centre in each of them (the 2x2 Bayer cell there), white-balanced by
`elphel_host.preview.white_balance` (as every picture) and shown with a display gamma of
1/2.2, scaled so the 99.5th percentile is white.

The pictures (`write_depth_products`) colour depth over its robust range and paint the
tiles left out in colours that are not on the colour map, each named in the legend:
texture-less, directions disagree, and far: at infinity or with a disparity below
`FAR_DISPARITY_PX`, whose depth is mostly the disparity's noise. Far points stay in the
cloud; its picture leaves them out and counts them.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
from numpy.typing import NDArray

from elphel_host.cloud.ply import PointCloud, write_ply
from elphel_host.cloud.render import cloud_png, depth_png, length_unit
from elphel_host.depth.geometry import DepthOptics
from elphel_host.errors import InputFormatError
from elphel_host.fileio import replacing
from elphel_host.preview import (
    DISAGREE_RGB,
    FAR_RGB,
    NO_VALUE_RGB,
    Swatch,
    number_text,
    white_balance,
)
from elphel_host.tp.bayer import lattices
from elphel_host.tp.geometry import tile_centres
from elphel_host.tp.images import QuadImages

F32 = NDArray[np.float32]

#: Default strength threshold: textured tiles of the simulator's scenes have strength
#: 0.3-0.5, texture-less ones ~0.1 (docs/tile-processor.md, Measured figures).
DEFAULT_MIN_STRENGTH = 0.15

#: Default largest disagreement between a tile's combined and per-direction disparities,
#: a fraction of the larger of the two.
DEFAULT_MAX_DISAGREEMENT = 0.25

#: Disagreements up to this many pixels are allowed whatever the disparity: a far tile's
#: directions differ by their noise (a few hundredths of a pixel on strong tiles, tenths
#: on weak ones), which is a large fraction of a small disparity.
DISAGREEMENT_FLOOR_PX = 0.25

#: Pictures show tiles under this disparity (px of the DSI) as far: their depth is
#: mostly noise (a tile's disparity noise is a few hundredths of a pixel on strong
#: tiles, tenths on weak ones).
FAR_DISPARITY_PX = 0.25

#: Why a tile has no depth, in `DepthResult.reason`.
KEPT, WEAK, INFINITE, INCONSISTENT = 0, 1, 2, 3

#: The DSI's per-direction layers: (disparity, strength).
DIRECTIONS = (
    ("disparity_hor", "strength_hor"),
    ("disparity_vert", "strength_vert"),
    ("disparity_diag", "strength_diag"),
)


@dataclass(frozen=True, eq=False)
class DepthResult:
    """Depth of every tile and the cloud of the kept ones.

    Attributes
    ----------
    depth_mm
        ``(tiles_y, tiles_x)`` float32, NaN where left out.
    cloud
        One point per kept tile (x, y, z mm, strength, colour).
    tiles, weak, infinite, inconsistent
        Tiles in all; left out for a strength below the threshold; left out for a
        disparity <= 0 (or not finite); left out because the directions disagree.
    min_strength, max_disagreement
        The thresholds used (``max_disagreement`` None: not checked).
    reason
        ``(tiles_y, tiles_x)`` uint8: `KEPT`, or why the tile is left out (`WEAK`,
        `INFINITE`, `INCONSISTENT`).
    """

    depth_mm: F32
    cloud: PointCloud
    reason: NDArray[np.uint8]
    tiles: int
    weak: int
    infinite: int
    min_strength: float
    inconsistent: int = 0
    max_disagreement: float | None = None

    def summary(self) -> dict[str, Any]:
        return {
            "tiles": self.tiles,
            "points": len(self.cloud),
            "weak_tiles": self.weak,
            "infinite_tiles": self.infinite,
            "inconsistent_tiles": self.inconsistent,
            "min_strength": self.min_strength,
            "max_disagreement": self.max_disagreement,
        }


def disagreeing(
    dsi: dict[str, F32], *, min_strength: float, max_disagreement: float
) -> NDArray[np.bool_]:
    """Tiles whose directions disagree on the disparity (see the module docstring).

    True where the combined disparity is more than ``max_disagreement`` (a fraction of the
    larger) and more than `DISAGREEMENT_FLOOR_PX` away from the median of the confident
    per-direction disparities. A direction
    is confident where its strength is at least ``min_strength``; tiles with none, and
    DSIs without the per-direction layers, disagree nowhere.
    """
    disparity = np.asarray(dsi["disparity"], dtype=np.float64)
    if not all(d in dsi and s in dsi for d, s in DIRECTIONS):
        return np.zeros(disparity.shape, dtype=bool)
    dirs = np.stack([np.asarray(dsi[d], dtype=np.float64) for d, _ in DIRECTIONS])
    conf = np.stack([np.asarray(dsi[s]) >= min_strength for _, s in DIRECTIONS])
    conf &= np.isfinite(dirs)
    any_conf = conf.any(axis=0)
    with np.errstate(invalid="ignore"):
        median = np.nanmedian(np.where(conf, dirs, np.nan)[:, any_conf], axis=0)
        bad = np.zeros(disparity.shape, dtype=bool)
        d = disparity[any_conf]
        tolerance = np.maximum(
            max_disagreement * np.maximum(np.abs(median), np.abs(d)), DISAGREEMENT_FLOOR_PX
        )
        bad[any_conf] = np.abs(d - median) > tolerance
    return bad


def _colours(
    quad: QuadImages, cx: F32, cy: F32, disparity: F32, rgb_images: F32 | None = None
) -> NDArray[np.uint8]:
    """Mean of the four cameras' 2x2 cells at each point's position in each camera."""
    n = cx.size
    rgb = np.zeros((n, 3), dtype=np.float64)
    h, w = quad.images.shape[1:]
    for cam in range(len(quad.geometry.positions)):
        img = quad.images[cam]
        x, y = quad.geometry.camera_pixels(cam, cx, cy, disparity)
        if rgb_images is not None:
            col = np.clip(np.floor(x).astype(np.intp), 0, w - 1)
            row = np.clip(np.floor(y).astype(np.intp), 0, h - 1)
            rgb += rgb_images[cam][row, col].astype(np.float64)
            continue
        # continuous coordinate x covers pixel floor(x); the cell containing it starts even
        col = np.clip(np.floor(x).astype(np.intp) // 2 * 2, 0, w - 2)
        row = np.clip(np.floor(y).astype(np.intp) // 2 * 2, 0, h - 2)
        if quad.bayer is None:
            v = img[row, col].astype(np.float64)
            rgb += v[:, None]
            continue
        sums = np.zeros((3, n))
        counts = np.zeros(3)
        for lat in lattices(quad.bayer):
            sums[lat.colour] += img[row + lat.row, col + lat.col]
            counts[lat.colour] += 1
        r, b, g = (sums[i] / counts[i] for i in range(3))
        rgb += np.stack([r, g, b], axis=1)
    rgb = white_balance(rgb / 4.0) if n else rgb
    white = float(np.percentile(rgb, 99.5)) if n else 1.0
    disp = np.clip(rgb / max(white, 1e-12), 0.0, 1.0) ** (1 / 2.2)
    out: NDArray[np.uint8] = np.round(disp * 255).astype(np.uint8)
    return out


def dsi_depth(
    dsi: dict[str, F32],
    quad: QuadImages,
    optics: DepthOptics,
    *,
    min_strength: float = DEFAULT_MIN_STRENGTH,
    max_disagreement: float | None = DEFAULT_MAX_DISAGREEMENT,
    rgb_images: F32 | None = None,
) -> DepthResult:
    """Depth map and point cloud of a DSI measured on ``quad`` (whose pixels ``optics`` describes).

    Parameters
    ----------
    dsi
        Layers with at least ``disparity`` and ``strength`` ``(tiles_y, tiles_x)``.
    quad
        The images the DSI was measured on (for the image size and the colours).
    optics
        Focal length, pixel pitch of these images (an up-sampled quad: :meth:`DepthOptics.scaled`)
        and baseline.
    min_strength
        Tiles below it are left out and counted.
    max_disagreement
        Tiles whose combined disparity is farther than this fraction from the median of
        their confident per-direction disparities are left out and counted (None: kept).
    rgb_images
        Optional ``(4, H, W, 3)`` colour images of the quad (a fused Bayer burst) to take
        the points' colours from instead of the quad's own images.
    """
    _check_dsi(dsi, quad, min_strength=min_strength, max_disagreement=max_disagreement)
    disparity = np.asarray(dsi["disparity"], dtype=np.float64)
    strength = np.asarray(dsi["strength"], dtype=np.float64)
    h, w = quad.images.shape[1:]
    infinite = ~(np.isfinite(disparity) & (disparity > 0))
    weak = ~infinite & ~(strength >= min_strength)
    inconsistent = ~infinite & ~weak
    if max_disagreement is None:
        inconsistent[...] = False
    else:
        inconsistent &= disagreeing(
            dsi, min_strength=min_strength, max_disagreement=max_disagreement
        )
    keep = ~infinite & ~weak & ~inconsistent
    depth = optics.depth_mm(np.where(keep, disparity, np.nan))
    cy, cx = tile_centres(*quad.tiles)
    pts = optics.points_mm(cx[keep], cy[keep], depth[keep], image_size=(w, h))
    colours = _colours(
        quad,
        cx[keep].astype(np.float32),
        cy[keep].astype(np.float32),
        disparity[keep].astype(np.float32),
        rgb_images,
    )
    cloud = PointCloud(pts.astype(np.float32), strength[keep].astype(np.float32), colours)
    reason = np.select([weak, infinite, inconsistent], [WEAK, INFINITE, INCONSISTENT], KEPT)
    return DepthResult(
        depth_mm=depth.astype(np.float32),
        cloud=cloud,
        reason=reason.astype(np.uint8),
        tiles=int(disparity.size),
        weak=int(np.count_nonzero(weak)),
        infinite=int(np.count_nonzero(infinite)),
        min_strength=float(min_strength),
        inconsistent=int(np.count_nonzero(inconsistent)),
        max_disagreement=None if max_disagreement is None else float(max_disagreement),
    )


def _check_dsi(
    dsi: dict[str, F32],
    quad: QuadImages,
    *,
    min_strength: float,
    max_disagreement: float | None,
) -> None:
    """The DSI has the layers and tiles ``dsi_depth`` needs; the limits are in range."""
    for name in ("disparity", "strength"):
        if name not in dsi:
            raise InputFormatError(f"DSI has no {name!r} layer; layers: {', '.join(dsi)}")
    if not min_strength >= 0:
        raise InputFormatError(f"min_strength={min_strength}; allowed: >= 0")
    if max_disagreement is not None and not max_disagreement > 0:
        raise InputFormatError(f"max_disagreement={max_disagreement}; allowed: > 0 or None")
    shape = np.shape(dsi["disparity"])
    if shape != quad.tiles:
        raise InputFormatError(
            f"DSI has {shape[1]}x{shape[0]} tiles, the quad {quad.tiles[1]}x{quad.tiles[0]}"
        )


def write_depth_tiff(path: str | Path, depth_mm: F32, *, metadata: dict[str, Any]) -> Path:
    """A float32 depth TIFF (mm, NaN = no depth), its metadata as JSON in the description."""
    path = Path(path)
    with replacing(path, sync=True, keep_suffix=True) as tmp:
        tifffile.imwrite(
            tmp, np.asarray(depth_mm, dtype=np.float32), metadata={"unit": "mm", **metadata}
        )
    return path


def read_depth_tiff(path: str | Path) -> tuple[F32, dict[str, Any]]:
    """Read a depth TIFF written by :func:`write_depth_tiff`: (depth mm, metadata)."""
    with tifffile.TiffFile(path) as tif:
        data = tif.asarray().astype(np.float32)
        desc = tif.pages.first.description
    try:
        meta = json.loads(desc) if desc else {}
    except json.JSONDecodeError as e:
        raise InputFormatError(f"{path}: description is not the JSON of a depth TIFF") from e
    return data, meta


def depth_paths(ply: str | Path) -> dict[str, Path]:
    """Where the products of ``--ply CLOUD.ply`` go: the cloud, its picture, the depth map."""
    ply = Path(ply)
    return {
        "ply": ply,
        "cloud_png": ply.with_suffix(".png"),
        "depth_tiff": ply.with_name(ply.stem + "_depth.tif"),
        "depth_png": ply.with_name(ply.stem + "_depth.png"),
    }


def left_out_swatches(result: DepthResult, far_mm: float) -> list[Swatch]:
    """The tiles a depth picture paints outside its colour map, named for the legend."""
    reason = result.reason
    weak = np.count_nonzero(reason == WEAK)
    with np.errstate(invalid="ignore"):
        far = (reason == INFINITE) | ((reason == KEPT) & (result.depth_mm > far_mm))
    unit, per = length_unit(far_mm)
    return [
        Swatch(
            f"far: disparity < {FAR_DISPARITY_PX:g} px, beyond {number_text(far_mm / per)} {unit} "
            f"({np.count_nonzero(far)} tiles)",
            far,
            FAR_RGB,
        ),
        Swatch(
            f"no texture: strength < {result.min_strength:g} ({weak} tiles)",
            reason == WEAK,
            NO_VALUE_RGB,
        ),
        Swatch(
            f"directions disagree ({np.count_nonzero(reason == INCONSISTENT)} tiles)",
            reason == INCONSISTENT,
            DISAGREE_RGB,
        ),
    ]


def write_depth_products(
    ply: str | Path, result: DepthResult, optics: DepthOptics, *, title: str = ""
) -> dict[str, str]:
    """Write the cloud (PLY + PNG views) and the depth map (TIFF + PNG with a colour bar)."""
    paths = depth_paths(ply)
    meta = {
        "min_strength": result.min_strength,
        "optics": {
            "focal_length_mm": optics.focal_length_mm,
            "pixel_pitch_um": optics.pixel_pitch_um,
            "baseline_mm": optics.baseline_mm,
        },
        "tile_centre": "(8*tx+4, 8*ty+4)",
        **result.summary(),
    }
    write_ply(
        paths["ply"],
        result.cloud,
        comments=("elphel depth: x y z in mm, camera frame of the virtual centre camera",),
    )
    far_mm = float(optics.depth_mm(np.array(FAR_DISPARITY_PX)))
    cloud_png(paths["cloud_png"], result.cloud, far_mm=far_mm, title=f"{title} cloud".strip())
    write_depth_tiff(paths["depth_tiff"], result.depth_mm, metadata=meta)
    depth_png(
        paths["depth_png"],
        result.depth_mm,
        title=f"{title} depth".strip(),
        swatches=left_out_swatches(result, far_mm),
    )
    return {k: str(v) for k, v in paths.items()}
