"""Pictures of a calibration a person reads at a glance, one PNG each, cameras side by side.

- residuals.png: per camera, the mean residual (detected minus predicted corner) in each
  cell of a 16 x 12 grid as an arrow, magnified to the scale printed on the picture;
  arrows that line up into swirls or rings mean the lens model misses something, arrows
  pointing every which way are noise.
- coverage.png: per camera, how many corners were seen in each cell (dark: none); the
  lens model is only measured where the picture is bright.
- uncertainty.png: per camera, the projection uncertainty over the image (px, colour
  scale printed on the picture).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from elphel_host.calibrate.solve import Calibration

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
            (80, 220, 255),
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


def _heat(values: NDArray[np.float64], lo: float, hi: float, size: tuple[int, int]) -> U8:
    norm = np.clip((values - lo) / max(hi - lo, 1e-12), 0, 1)
    norm = np.where(np.isfinite(norm), norm, 0)
    small = (norm * 255).astype(np.uint8)
    big = cv2.resize(small, size, interpolation=cv2.INTER_NEAREST)
    return np.asarray(cv2.applyColorMap(big, cv2.COLORMAP_VIRIDIS), dtype=np.uint8)


def coverage_tile(cal: Calibration, camera: int) -> U8:
    cam = cal.cameras[camera]
    w, h = cam.lens.width, cam.lens.height
    count, _ = _cells(cam.residuals, w, h)
    size = (TILE_WIDTH, round(h * TILE_WIDTH / w))
    tile = _heat(count.astype(np.float64), 0, max(float(count.max()), 1.0), size)
    empty = float(np.mean(count == 0))
    return _headed(
        tile,
        [
            f"cam{camera}  {cam.corners} corners, max {count.max()} per cell",
            f"cells with no corner: {100 * empty:.0f} %",
        ],
    )


def uncertainty_tile(cal: Calibration, camera: int, hi: float) -> U8:
    cam = cal.cameras[camera]
    w, h = cam.lens.width, cam.lens.height
    size = (TILE_WIDTH, round(h * TILE_WIDTH / w))
    tile = _heat(cam.uncertainty_map, 0.0, hi, size)
    return _headed(
        tile,
        [
            f"cam{camera}  projection uncertainty, rms {cam.uncertainty_px:.4f} px",
            f"colour: 0 (dark) .. {hi:.4f} px (yellow)",
        ],
    )


def _side_by_side(tiles: list[U8]) -> U8:
    h = max(t.shape[0] for t in tiles)
    padded = [np.pad(t, ((0, h - t.shape[0]), (0, 4), (0, 0))) for t in tiles]
    if len(padded) <= 2:
        return np.hstack(padded)
    rows = [
        np.hstack(padded[i : i + 2] + [np.zeros_like(padded[0])] * (2 - len(padded[i : i + 2])))
        for i in range(0, len(padded), 2)
    ]
    return np.vstack(rows)


def write_pictures(cal: Calibration, out_dir: str | Path) -> list[Path]:
    """Write residuals.png, coverage.png and uncertainty.png; return their paths."""
    out = Path(out_dir)
    n = len(cal.cameras)
    maps = [c.uncertainty_map for c in cal.cameras]
    hi = max(float(np.nanpercentile(m, 95)) for m in maps)
    pictures = {
        "residuals.png": [residual_tile(cal, c) for c in range(n)],
        "coverage.png": [coverage_tile(cal, c) for c in range(n)],
        "uncertainty.png": [uncertainty_tile(cal, c, hi) for c in range(n)],
    }
    paths = []
    for name, tiles in pictures.items():
        path = out / name
        ok, data = cv2.imencode(".png", _side_by_side(tiles))
        if not ok:
            raise OSError(f"{path}: PNG encoding failed")
        path.write_bytes(data.tobytes())
        paths.append(path)
    return paths
