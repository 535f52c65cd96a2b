"""Pictures of a calibration a person reads at a glance, one PNG each, cameras side by side.

- residuals.png: per camera, the mean residual (detected minus predicted corner) in each
  cell of a 16 x 12 grid as an arrow, magnified to the scale printed on the picture;
  arrows that line up into swirls or rings mean the lens model misses something, arrows
  pointing every which way are noise.
- coverage.png: per camera, how many corners were seen in each cell (dark: none), with
  its colour bar; the lens model is only measured where the picture is bright.
- uncertainty.png: per camera, the projection uncertainty over the image, with its colour
  bar in px (one scale for all cameras).

The maps are `elphel_host.preview.map_picture`'s, as every map of the project is.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from elphel_host.calibrate.solve import Calibration
from elphel_host.preview import BACKGROUND_RGB, map_picture, save_png

TILE_WIDTH = 480
CELLS = (16, 12)
U8 = NDArray[np.uint8]


def _cells(
    res: NDArray[np.float64], width: int, height: int
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Per cell of `CELLS`: the corner count and the mean residual ``(rows, cols, 2)``."""
    nx, ny = CELLS
    ix = np.clip((res[:, 0] * nx / width).astype(int), 0, nx - 1)
    iy = np.clip((res[:, 1] * ny / height).astype(int), 0, ny - 1)
    count = np.zeros((ny, nx), dtype=np.int64)
    total = np.zeros((ny, nx, 2))
    np.add.at(count, (iy, ix), 1)
    np.add.at(total, (iy, ix), res[:, 2:4])
    return count, total / np.maximum(count, 1)[..., None]


def _headed(tile: U8, lines: list[str]) -> U8:
    """``tile`` under a black header carrying ``lines`` (the picture is left uncovered)."""
    header = np.zeros((8 + 18 * len(lines), tile.shape[1], 3), dtype=np.uint8)
    for row, text in enumerate(lines):
        cv2.putText(
            header,
            text,
            (6, 18 + 18 * row),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.5,
            (255, 255, 255),
            1,
            cv2.LINE_AA,
        )
    return np.vstack([header, tile])


def residual_tile(cal: Calibration, camera: int) -> U8:
    """Mean residual arrows per cell over the corners used (RGB)."""
    cam = cal.cameras[camera]
    w, h = cam.lens.width, cam.lens.height
    s = TILE_WIDTH / w
    tile = np.full((round(h * s), TILE_WIDTH, 3), 40, dtype=np.uint8)
    count, mean = _cells(cam.residuals, w, h)
    longest = (
        float(np.percentile(np.linalg.norm(mean[count > 0], axis=-1), 95)) if count.any() else 0.0
    )
    cell_px = TILE_WIDTH / CELLS[0]
    gain = 0.9 * cell_px / max(longest, 1e-6)  # picture px per residual px
    for x, y in cam.residuals[:, :2] * s:
        cv2.circle(tile, (round(x), round(y)), 1, (90, 90, 90), -1)
    for iy, ix in zip(*np.nonzero(count), strict=True):
        c = np.array([(ix + 0.5) * cell_px, (iy + 0.5) * TILE_WIDTH / w * h / CELLS[1]])
        tip = c + mean[iy, ix] * gain
        cv2.arrowedLine(
            tile,
            tuple(np.round(c).astype(int)),
            tuple(np.round(tip).astype(int)),
            (255, 220, 80),
            1,
            cv2.LINE_AA,
            tipLength=0.3,
        )
    return _headed(
        tile,
        [
            f"cam{camera}  rms {cam.rms_px:.4f} px",
            f"arrow of one cell width = {0.9 * cell_px / gain:.4f} px",
        ],
    )


def coverage_tile(cal: Calibration, camera: int) -> U8:
    """Corners seen per cell of `CELLS`, with its colour bar (RGB)."""
    cam = cal.cameras[camera]
    count, _ = _cells(cam.residuals, cam.lens.width, cam.lens.height)
    empty = 100 * float(np.mean(count == 0))
    return map_picture(
        count.astype(np.float64),
        unit="corners",
        title=f"cam{camera}: corners per cell, {cam.corners} in all, {empty:.0f} % of cells none",
        lo=0.0,
        hi=max(float(count.max()), 1.0),
        cell=TILE_WIDTH // CELLS[0],
    )


def uncertainty_tile(cal: Calibration, camera: int, hi: float) -> U8:
    """The projection uncertainty map, one colour scale for all cameras (RGB)."""
    cam = cal.cameras[camera]
    cols = cam.uncertainty_map.shape[1]
    return map_picture(
        cam.uncertainty_map,
        unit="px",
        title=f"cam{camera}: projection uncertainty, RMS {cam.uncertainty_px:.4f} px",
        lo=0.0,
        hi=hi,
        no_value="the lens model folds here (no projection)",
        cell=max(1, TILE_WIDTH // max(cols, 1)),
    )


def side_by_side(tiles: list[U8]) -> U8:
    """Pictures two to a row on the pictures' background, each padded to the largest."""
    h = max(t.shape[0] for t in tiles) + 6
    w = max(t.shape[1] for t in tiles) + 6
    padded = []
    for t in tiles:
        cell = np.empty((h, w, 3), dtype=np.uint8)
        cell[:] = BACKGROUND_RGB
        cell[: t.shape[0], : t.shape[1]] = t
        padded.append(cell)
    if len(padded) % 2 and len(padded) > 1:
        padded.append(np.full_like(padded[0], BACKGROUND_RGB))
    rows = [np.hstack(padded[i : i + 2]) for i in range(0, len(padded), 2)]
    return np.vstack(rows)


def write_pictures(cal: Calibration, out_dir: str | Path) -> list[Path]:
    """Write residuals.png, coverage.png and uncertainty.png; return their paths."""
    out = Path(out_dir)
    n = len(cal.cameras)
    hi = max(float(np.nanpercentile(c.uncertainty_map, 95)) for c in cal.cameras)
    pictures = {
        "residuals.png": [residual_tile(cal, c) for c in range(n)],
        "coverage.png": [coverage_tile(cal, c) for c in range(n)],
        "uncertainty.png": [uncertainty_tile(cal, c, max(hi, 1e-6)) for c in range(n)],
    }
    return [save_png(side_by_side(tiles), out / name) for name, tiles in pictures.items()]
