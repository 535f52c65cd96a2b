"""A printed checkerboard as an object of the simulated world, and how a lens sees it.

The board lies in its own plane z = 0, its inner corners at ``(i, j) * square_mm``
(`elphel_host.calibrate.pattern.Checkerboard`), inside a white margin. `board_radiance`
gives the radiance a camera sees at each pixel from the board coordinates of the pixel's
centre and their derivatives across the pixel: every sample inside the pixel is placed
by that local affine map, and at each sample the board is blurred by the lens's Gaussian
PSF edge by edge (an erf across each line of squares, the product of the two line
families). The blurred pattern is point-symmetric about each corner, so the blur moves
no corner; the samples average the pixel's area.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.special import erf

from elphel_host.calibrate.pattern import Checkerboard

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class PrintedBoard:
    """A checkerboard as printed: its pattern, its margin and its inks.

    ``margin_squares`` of white paper surround the squares; ``black`` and ``white`` are
    the inks' reflectances and ``colour`` the illuminant's RGB (the same for both inks,
    as under one lamp); ``background`` is the radiance around the board.
    """

    pattern: Checkerboard
    margin_squares: float = 0.6
    black: float = 0.08
    white: float = 0.9
    colour: tuple[float, float, float] = (0.95, 1.0, 0.85)
    background: float = 0.3

    @property
    def squares(self) -> tuple[int, int]:
        """Squares along the board's x and y."""
        return self.pattern.cols + 1, self.pattern.rows + 1

    def outline_mm(self) -> FloatArray:
        """The paper's four corners ``(4, 3)`` in the board's frame."""
        sq, m = self.pattern.square_mm, self.margin_squares
        nx, ny = self.squares
        x0, y0 = -(1 + m) * sq, -(1 + m) * sq
        x1, y1 = (nx - 1 + m) * sq, (ny - 1 + m) * sq
        return np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])


def _edge(t: FloatArray, grad: FloatArray, sigma_px: FloatArray) -> FloatArray:
    """Blurred step ``erf`` across the nearest line ``t = k`` (t in squares, grad in squares/px)."""
    d_px = (t - np.rint(t)) / np.maximum(grad, 1e-12)
    out: FloatArray = erf(d_px / (np.sqrt(2.0) * sigma_px))
    return out


def _inside(
    t: FloatArray, grad: FloatArray, sigma_px: FloatArray, lo: float, hi: float
) -> FloatArray:
    """Blurred indicator of ``lo <= t <= hi``."""
    s = np.sqrt(2.0) * sigma_px * np.maximum(grad, 1e-12)
    out: FloatArray = 0.5 * (erf((t - lo) / s) - erf((t - hi) / s))
    return out


def board_radiance(
    board: PrintedBoard,
    u: FloatArray,
    v: FloatArray,
    jacobian: FloatArray,
    sigma_px: FloatArray,
    *,
    samples: int = 4,
) -> FloatArray:
    """The grey radiance (before the illuminant's colour) seen at each pixel.

    Parameters
    ----------
    board
        The printed board.
    u, v
        ``(H, W)`` board coordinates in squares at each pixel's centre (corner (i, j) at
        ``(i + 1, j + 1)``; NaN where the ray misses the board's plane).
    jacobian
        ``(H, W, 2, 2)``: d(u, v)/d(x, y) per pixel.
    sigma_px
        ``(H, W)`` the lens's Gaussian PSF sigma at each pixel (sensor px, > 0).
    samples
        Samples per pixel along each axis (the pixel's area is their mean).
    """
    nx, ny = board.squares
    m = board.margin_squares
    gu = np.hypot(jacobian[..., 0, 0], jacobian[..., 0, 1])
    gv = np.hypot(jacobian[..., 1, 0], jacobian[..., 1, 1])
    total = np.zeros(u.shape)
    offsets = (np.arange(samples) + 0.5) / samples - 0.5
    for dy in offsets:
        for dx in offsets:
            us = u + jacobian[..., 0, 0] * dx + jacobian[..., 0, 1] * dy
            vs = v + jacobian[..., 1, 0] * dx + jacobian[..., 1, 1] * dy
            parity = np.where((np.floor(np.rint(us)) + np.floor(np.rint(vs))) % 2 == 0, 1.0, -1.0)
            # (-1)^(floor u + floor v) blurred: the product of the two edges' erfs
            checker = parity * _edge(us, gu, sigma_px) * _edge(vs, gv, sigma_px)
            squares = _inside(us, gu, sigma_px, 0.0, nx) * _inside(vs, gv, sigma_px, 0.0, ny)
            paper = _inside(us, gu, sigma_px, -m, nx + m) * _inside(vs, gv, sigma_px, -m, ny + m)
            dark = 0.5 * (1.0 + checker) * squares
            grey = board.white - (board.white - board.black) * dark
            total += paper * grey + (1.0 - paper) * board.background
    out = total / samples**2
    return np.where(np.isnan(out), board.background, out)
