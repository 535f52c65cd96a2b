"""Quad geometry: camera positions, pairs, and where each camera's tile lies.

Disparity convention (docs/tile-processor.md, Files): a point seen at p by the virtual
centre camera is seen by camera i at ``p - D * position_i``; positions are in units of
the square's side, +x right, +y down. Tile (tx, ty) of the virtual camera is centred at
``(8tx + 4, 8ty + 4)``. A calibrated quad (quad.json ``"calibration"``) places its tiles
through a :class:`TileMap` instead (:mod:`elphel_host.tp.calibrated`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from elphel_host.errors import InputFormatError

IDEAL_POSITIONS = ((-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5))
#: The six pairs (first, second): top, bottom, left, right, main diagonal, other diagonal.
PAIRS = ((0, 1), (2, 3), (0, 2), (1, 3), (0, 3), (2, 1))


class TileMap(Protocol):
    """Where each camera sees the virtual camera's tiles, when that is not the ideal square."""

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of the images the map is for."""
        ...

    def pixels(
        self,
        camera: int,
        cx: NDArray[np.floating],
        cy: NDArray[np.floating],
        disparity: NDArray[np.floating],
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Continuous pixel (x, y) in ``camera`` of the virtual camera's (cx, cy) at a disparity."""
        ...

    def disparity_gain(
        self,
        cx: NDArray[np.floating],
        cy: NDArray[np.floating],
        pairs: Sequence[tuple[int, int]],
        vectors: NDArray[np.float64],
    ) -> NDArray[np.float64]:
        """Per tile, the pixels the pairs' separations move per unit of disparity."""
        ...

    def place(
        self,
        camera: int,
        cx: NDArray[np.floating],
        cy: NDArray[np.floating],
        disparity: NDArray[np.floating],
    ) -> TilePlacement:
        """:func:`window_at` of :meth:`pixels` along each axis."""
        ...


@dataclass(frozen=True)
class QuadGeometry:
    """Camera centres of a quad (in units of the square's side) and the pairs correlated.

    ``calibration``: where a calibrated quad's cameras see each tile (None: the ideal
    square, ``p - D * position``).
    """

    positions: tuple[tuple[float, float], ...] = IDEAL_POSITIONS
    pairs: tuple[tuple[int, int], ...] = field(default=PAIRS)
    calibration: TileMap | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        if len(self.positions) != 4 or any(len(p) != 2 for p in self.positions):
            raise InputFormatError(f"positions must be 4 (x, y) pairs, got {self.positions!r}")
        for a, b in self.pairs:
            if not (0 <= a < 4 and 0 <= b < 4 and a != b):
                raise InputFormatError(f"pair ({a}, {b}); allowed: two different cameras 0..3")

    def pair_vectors(self) -> NDArray[np.float64]:
        """Per pair, the lag (dx, dy) of the correlation peak per unit of residual disparity.

        Content of camera i moves by ``-delta * position_i``, so the peak of the correlation
        of (a, b) (peak at position in b minus position in a) lies at
        ``delta * (position_a - position_b)``.
        """
        p = np.asarray(self.positions, dtype=np.float64)
        return np.array([p[a] - p[b] for a, b in self.pairs])

    def place_camera(
        self,
        camera: int,
        cx: NDArray[np.floating],
        cy: NDArray[np.floating],
        disparity: NDArray[np.floating],
    ) -> TilePlacement:
        """Camera ``camera``'s tiles centred at (cx, cy) at a disparity (see :func:`place`)."""
        if self.calibration is None:
            return place_tiles(cx, cy, disparity, self.positions[camera])
        return self.calibration.place(camera, cx, cy, disparity)

    def camera_pixels(
        self,
        camera: int,
        cx: NDArray[np.floating],
        cy: NDArray[np.floating],
        disparity: NDArray[np.floating],
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Continuous pixel (x, y) in ``camera`` of what the virtual camera sees at (cx, cy)."""
        if self.calibration is not None:
            return self.calibration.pixels(camera, cx, cy, disparity)
        px, py = self.positions[camera]
        d = np.asarray(disparity, dtype=np.float64)
        return np.asarray(cx, dtype=np.float64) - d * px, np.asarray(cy, dtype=np.float64) - d * py

    def disparity_gain(
        self, cx: NDArray[np.floating], cy: NDArray[np.floating]
    ) -> NDArray[np.float64]:
        """Per tile, the raw pixels a pair's peak moves per unit of disparity (1 if ideal)."""
        if self.calibration is None:
            return np.ones(np.shape(cx))
        return self.calibration.disparity_gain(cx, cy, self.pairs, self.pair_vectors())


def tile_centres(tiles_y: int, tiles_x: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Centres (cy, cx) of all tiles, each shaped (tiles_y, tiles_x)."""
    cy, cx = np.meshgrid(
        8.0 * np.arange(tiles_y) + 4.0, 8.0 * np.arange(tiles_x) + 4.0, indexing="ij"
    )
    return cy, cx


def place(
    centre: NDArray[np.floating], disparity: NDArray[np.floating], position: float
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Integer left edge and residual shift of one camera's tiles along one axis.

    Parameters
    ----------
    centre
        Virtual-camera tile centres along the axis (pixels).
    disparity
        Target disparity per tile.
    position
        The camera's coordinate along the axis (units of the square's side).

    Returns
    -------
    left, shift
        ``left`` = the integer first pixel of the 16-sample window, ``shift`` = s in
        [-0.5, 0.5] such that the tile is the image sampled at ``left - s + j``.
    """
    return window_at(
        np.asarray(centre, dtype=np.float64) - np.asarray(disparity, dtype=np.float64) * position
    )


def window_at(centre_px: NDArray[np.floating]) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Integer left edge and residual shift of 16-sample windows centred at continuous pixels.

    Returns
    -------
    left, shift
        As :func:`place`: the window is the image sampled at ``left - shift + j``.
    """
    p = np.asarray(centre_px, dtype=np.float64) - 8.0
    left = np.floor(p + 0.5)
    return left.astype(np.int64), left - p


@dataclass(frozen=True, eq=False)
class TilePlacement:
    """Where one camera's tiles lie on its sensor, each field ``(T,)`` (see :func:`place`).

    Attributes
    ----------
    left_x, top_y
        Integer first pixel of each tile's 16-sample window.
    shift_x, shift_y
        Residual shifts s in [-0.5, 0.5]: the tile is the image sampled at ``left - s + j``.
    """

    left_x: NDArray[np.int64]
    shift_x: NDArray[np.float64]
    top_y: NDArray[np.int64]
    shift_y: NDArray[np.float64]


def place_tiles(
    cx: NDArray[np.floating],
    cy: NDArray[np.floating],
    disparity: NDArray[np.floating],
    position: tuple[float, float],
) -> TilePlacement:
    """:func:`place` along both axes: one camera's tiles centred at (cx, cy) at a disparity."""
    left_x, shift_x = place(cx, disparity, position[0])
    top_y, shift_y = place(cy, disparity, position[1])
    return TilePlacement(left_x=left_x, shift_x=shift_x, top_y=top_y, shift_y=shift_y)
