"""The calibration pattern: a checkerboard and its ``checkerboard:COLSxROWS:SQUARE_MM`` SPEC."""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

_SPEC = re.compile(r"^checkerboard:(\d+)x(\d+):([0-9]*\.?[0-9]+)$")


@dataclass(frozen=True)
class Checkerboard:
    """A checkerboard by its inner corners: ``cols`` x ``rows`` corners, ``square_mm`` apart.

    Its corners, row by row (columns fastest), lie at ``(i * square_mm, j * square_mm, 0)``
    in the board's frame. The square diagonally outside corner 0 is black and the one
    outside the last corner is white: ``cols + rows`` must be odd, so that a board turned
    by 180 degrees is told apart from one that is not.
    """

    cols: int
    rows: int
    square_mm: float

    def __post_init__(self) -> None:
        if self.cols < 3 or self.rows < 3:
            raise ValueError(
                f"checkerboard {self.cols}x{self.rows} inner corners; allowed: at least 3x3"
            )
        if (self.cols + self.rows) % 2 == 0:
            raise ValueError(
                f"checkerboard {self.cols}x{self.rows}: cols + rows must be odd (e.g. 9x6) "
                "so that the board's orientation is unambiguous"
            )
        if not self.square_mm > 0:
            raise ValueError(f"square_mm={self.square_mm}; allowed: > 0")

    @classmethod
    def parse(cls, spec: str) -> Checkerboard:
        """The board of a SPEC such as ``checkerboard:9x6:25``; ValueError names the form."""
        m = _SPEC.match(spec.strip())
        if m is None:
            raise ValueError(
                f"pattern {spec!r}; allowed: checkerboard:COLSxROWS:SQUARE_MM "
                "(inner corners, e.g. checkerboard:9x6:25)"
            )
        return cls(int(m.group(1)), int(m.group(2)), float(m.group(3)))

    @property
    def spec(self) -> str:
        return f"checkerboard:{self.cols}x{self.rows}:{self.square_mm:g}"

    @property
    def count(self) -> int:
        return self.cols * self.rows

    def object_points_mm(self) -> NDArray[np.float64]:
        """``(rows * cols, 3)`` corner positions in the board's frame (flat board)."""
        j, i = np.mgrid[0 : self.rows, 0 : self.cols]
        pts = np.zeros((self.count, 3))
        pts[:, 0] = i.ravel() * self.square_mm
        pts[:, 1] = j.ravel() * self.square_mm
        return pts
