"""A lens's smooth residual: pixel offsets the rational model cannot follow, on a spline.

A real lens is not exactly radial: decentred elements and a tilted sensor leave a smooth,
non-radial error of a few hundredths to a few tenths of a pixel that OpenCV's rational
model cannot express. The residual grid adds it after the model, as Elphel's non-radial
correction and mrcal's splined models do: a uniform cubic B-spline over the image, with
``cells = (cx, cy)`` spans along x and y and so ``(cy + 3, cx + 3)`` control offsets per
axis. A pixel ``u`` of an image ``width`` wide sits at ``t = (u + 0.5) / width * cx``
spans from the left edge; the four controls around it weigh in by the cubic B-spline's
basis. The mapping is the same at every image scale (``u' = s u + (s - 1) / 2``), so a
scaled lens (`scaled`) keeps its controls, multiplied by ``s``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

#: The spans along x and y of a grid on a 4:3 image when the solve is not told.
DEFAULT_CELLS = (6, 4)


def spline_weights(t: FloatArray, spans: int) -> tuple[IntArray, FloatArray]:
    """The first control index ``(N,)`` and the four weights ``(N, 4)`` at positions ``t``.

    ``t`` is in spans from the first edge; outside ``0..spans`` the end span's
    polynomial is extended.
    """
    i = np.clip(np.floor(t), 0, spans - 1).astype(np.intp)
    f = t - i
    f2, f3 = f * f, f * f * f
    w = np.stack([(1 - f) ** 3, 3 * f3 - 6 * f2 + 4, -3 * f3 + 3 * f2 + 3 * f + 1, f3], axis=-1)
    return i, w / 6.0


@dataclass(frozen=True)
class ResidualGrid:
    """The offsets ``(cy + 3, cx + 3, 2)`` (px) of the controls over a ``width x height`` image."""

    width: int
    height: int
    controls_px: FloatArray

    def __post_init__(self) -> None:
        c = np.asarray(self.controls_px)
        if c.ndim != 3 or c.shape[2] != 2 or c.shape[0] < 4 or c.shape[1] < 4:
            raise ValueError(
                f"residual grid controls of shape {c.shape}; allowed: (rows >= 4, cols >= 4, 2)"
            )
        if not np.isfinite(c).all():
            raise ValueError("residual grid controls must be finite numbers")

    @property
    def cells(self) -> tuple[int, int]:
        """Spans along x and y."""
        return self.controls_px.shape[1] - 3, self.controls_px.shape[0] - 3

    @classmethod
    def zeros(cls, width: int, height: int, cells: tuple[int, int]) -> ResidualGrid:
        cx, cy = cells
        return cls(width, height, np.zeros((cy + 3, cx + 3, 2)))

    def basis(self, pixels: FloatArray) -> tuple[IntArray, FloatArray]:
        """Per pixel ``(N, 2)``, its 16 controls' flat indices ``(N, 16)`` and weights ``(N, 16)``.

        A flat index counts controls row by row (``row * (cx + 3) + col``).
        """
        cx, cy = self.cells
        p = np.asarray(pixels, dtype=np.float64)
        ix, wx = spline_weights((p[:, 0] + 0.5) / self.width * cx, cx)
        iy, wy = spline_weights((p[:, 1] + 0.5) / self.height * cy, cy)
        cols = ix[:, None] + np.arange(4)
        rows = iy[:, None] + np.arange(4)
        index = (rows[:, :, None] * (cx + 3) + cols[:, None, :]).reshape(-1, 16)
        weight = (wy[:, :, None] * wx[:, None, :]).reshape(-1, 16)
        return index, weight

    def at(self, pixels: FloatArray) -> FloatArray:
        """The offsets ``(N, 2)`` in px at pixels ``(N, 2)``."""
        index, weight = self.basis(pixels)
        flat = self.controls_px.reshape(-1, 2)
        out: FloatArray = np.einsum("nk,nkc->nc", weight, flat[index])
        return out

    def scaled(self, scale: int) -> ResidualGrid:
        """The same residual on the image up-sampled ``scale`` times."""
        return ResidualGrid(self.width * scale, self.height * scale, self.controls_px * scale)

    def size_px(self, *, step_px: float = 16.0) -> tuple[float, float]:
        """RMS and largest length (px) of the offsets over the image, on a ``step_px`` grid."""
        xs = np.arange(0, self.width, step_px)
        ys = np.arange(0, self.height, step_px)
        gx, gy = np.meshgrid(xs, ys)
        d = np.linalg.norm(self.at(np.column_stack([gx.ravel(), gy.ravel()])), axis=1)
        return float(np.sqrt(np.mean(d**2))), float(d.max())

    def to_json(self) -> dict[str, object]:
        return {
            "model": "cubic-bspline",
            "cells": list(self.cells),
            "controls_px": np.round(self.controls_px, 6).tolist(),
        }

    @classmethod
    def from_json(cls, width: int, height: int, data: object) -> ResidualGrid:
        if not isinstance(data, dict) or data.get("model") != "cubic-bspline":
            raise ValueError(
                f"residual_grid {str(data)[:80]!r}; allowed: {{'model': 'cubic-bspline', ...}}"
            )
        controls = np.asarray(data.get("controls_px"), dtype=np.float64)
        grid = cls(width, height, controls)
        if list(grid.cells) != list(data.get("cells", [])):
            raise ValueError(
                f"residual_grid cells {data.get('cells')!r} do not match its "
                f"{controls.shape[1]}x{controls.shape[0]} controls; allowed: controls "
                "(cells_y + 3) x (cells_x + 3)"
            )
        return grid
