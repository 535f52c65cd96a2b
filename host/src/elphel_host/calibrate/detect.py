"""Checkerboard corners to a few hundredths of a pixel, each with its uncertainty.

OpenCV's ``findChessboardCornersSB`` finds the board and orders its corners; then every
corner is refined by fitting the image of a blurred corner to the pixels around it: two
straight edges through ``(x0, y0)`` at angles ``a1``, ``a2``, each blurred to an erf of
width ``s``, their product scaled by ``A`` over a level ``m`` (7 parameters, Gauss-Newton,
all the corners of a view at once). The blurred checkerboard is point-symmetric about
its corner, so the lens's blur and the pixels' area move the fitted corner nowhere; the
fit's covariance, scaled by its residual, is the corner's uncertainty.

A Bayer frame is never demosaiced: each of its four colour phases is divided by its
mean, which turns a grey board under any illuminant into one grey image at full
resolution.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from scipy.special import erf

from elphel_host.calibrate.pattern import Checkerboard

FloatArray = NDArray[np.float64]

_SQRT2 = np.sqrt(2.0)
_ITERATIONS = 12


@dataclass(frozen=True)
class Corners:
    """The corners of one board in one image, row by row (columns fastest).

    ``pixels`` ``(N, 2)``; ``sigma_px`` ``(N,)`` each corner's estimated standard error
    along x and along y (their root mean square); ``blur_px`` ``(N,)`` the fitted edge
    width (the PSF's sigma with the pixel's area folded in).
    """

    pixels: FloatArray
    sigma_px: FloatArray
    blur_px: FloatArray


def grey_image(image: NDArray[np.generic], bayer: str | None) -> FloatArray:
    """A float grey image: a Bayer frame's four phases each divided by its mean; RGB averaged."""
    a = np.asarray(image, dtype=np.float64)
    if a.ndim == 3:
        return np.asarray(a.mean(axis=2))
    if a.ndim != 2:
        raise ValueError(f"image has shape {a.shape}; allowed: (H, W) or (H, W, 3)")
    if bayer is None:
        return a
    out = a.copy()
    overall = a.mean()
    for dy in (0, 1):
        for dx in (0, 1):
            phase = a[dy::2, dx::2]
            mean = phase.mean()
            if mean > 0:
                out[dy::2, dx::2] = phase * (overall / mean)
    return out


def eight_bit(grey: FloatArray) -> NDArray[np.uint8]:
    """``grey`` scaled to 8 bits between its 0.5th and 99.5th percentiles (OpenCV's input)."""
    lo, hi = np.percentile(grey, (0.5, 99.5))
    scaled = (grey - lo) * (255.0 / max(hi - lo, 1e-9))
    out: NDArray[np.uint8] = np.clip(scaled, 0, 255).astype(np.uint8)
    return out


def _sample(grey: FloatArray, xy: FloatArray) -> FloatArray:
    out: FloatArray = ndimage.map_coordinates(grey, [xy[:, 1], xy[:, 0]], order=1, mode="nearest")
    return out


def _orient(grey: FloatArray, corners: FloatArray, board: Checkerboard) -> FloatArray:
    """The corners in the board's own order: corner 0 has the black square outside it."""
    grid = corners.reshape(board.rows, board.cols, 2)
    ex, ey = grid[0, 1] - grid[0, 0], grid[1, 0] - grid[0, 0]
    if ex[0] * ey[1] - ex[1] * ey[0] < 0:  # a mirrored order: rows reversed
        grid = grid[::-1]
        ex, ey = grid[0, 1] - grid[0, 0], grid[1, 0] - grid[0, 0]
    c0 = grid[0, 0]
    outside = np.array([c0 - 0.5 * ex - 0.5 * ey, c0 - 0.5 * ex + 0.5 * ey])
    black, white = _sample(grey, outside)
    if black > white:
        grid = grid[::-1, ::-1]
    return grid.reshape(-1, 2).copy()


#: Images wider than this are searched at half (or quarter) size first: the search costs
#: as the pixels do, and the fit refines at full resolution from there.
SEARCH_WIDTH_PX = 1000


def _search(
    image: NDArray[np.uint8], size: tuple[int, int], *, thorough: bool
) -> FloatArray | None:
    """OpenCV's corners (about 0.1 px) in OpenCV's order, or None.

    ``thorough`` adds the exhaustive SB search and the classic detector (which finds some
    steep views SB misses, but takes seconds on a large image without a whole board).
    """
    for flags in (0, cv2.CALIB_CB_EXHAUSTIVE) if thorough else (0,):
        found, corners = cv2.findChessboardCornersSB(image, size, flags=flags)
        if found:
            return np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    if not thorough:
        return None
    found, corners = cv2.findChessboardCorners(image, size)
    if not found:
        return None
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.01)
    corners = cv2.cornerSubPix(image, corners, (4, 4), (-1, -1), criteria)
    return np.asarray(corners, dtype=np.float64).reshape(-1, 2)


def find_corners(grey: FloatArray, board: Checkerboard) -> FloatArray | None:
    """Corners ``(N, 2)`` to a few tenths of a pixel in the board's order, or None."""
    size = (board.cols, board.rows)
    image = eight_bit(grey)
    corners = None
    factor = 1
    while image.shape[1] / factor > SEARCH_WIDTH_PX:
        factor *= 2
    if factor > 1:
        small = np.asarray(
            cv2.resize(image, None, fx=1 / factor, fy=1 / factor, interpolation=cv2.INTER_AREA),
            dtype=np.uint8,
        )
        found = _search(small, size, thorough=True)
        if found is not None:  # a small pixel i covers full pixels factor*i .. factor*i+factor-1
            corners = found * factor + (factor - 1) / 2
    if corners is None:  # squares too small for the reduced copy: the full image, quickly
        corners = _search(image, size, thorough=factor == 1)
    if corners is None:
        return None
    ordered = _orient(grey, corners, board)
    return ordered if _whole_board(grey, ordered, board) else None


def _whole_board(grey: FloatArray, corners: FloatArray, board: Checkerboard) -> bool:
    """True unless squares continue beyond the corners found (a part of a larger board)."""
    grid = corners.reshape(board.rows, board.cols, 2)
    centres = 0.25 * (grid[:-1, :-1] + grid[1:, :-1] + grid[:-1, 1:] + grid[1:, 1:]).reshape(-1, 2)
    levels = _sample(grey, centres)
    threshold = 0.5 * (np.percentile(levels, 10) + np.percentile(levels, 90))
    beyond = []
    for edge, inner in (
        (grid[0], grid[1]),
        (grid[-1], grid[-2]),
        (grid[:, 0], grid[:, 1]),
        (grid[:, -1], grid[:, -2]),
    ):
        mid_e, mid_i = 0.5 * (edge[1:] + edge[:-1]), 0.5 * (inner[1:] + inner[:-1])
        beyond.append(mid_e + 1.25 * (mid_e - mid_i))
    points = np.concatenate(beyond)
    h, w = grey.shape
    seen = (
        (points[:, 0] >= 0)
        & (points[:, 0] <= w - 1)
        & (points[:, 1] >= 0)
        & (points[:, 1] <= h - 1)
    )
    return not np.any(_sample(grey, points[seen]) < threshold)


def _grid_directions(
    corners: FloatArray, board: Checkerboard
) -> tuple[FloatArray, FloatArray, float]:
    """Angles of the row and column directions at each corner, and the smallest spacing."""
    grid = corners.reshape(board.rows, board.cols, 2)
    along_row = np.asarray(np.gradient(grid, axis=1)).reshape(-1, 2)
    along_col = np.asarray(np.gradient(grid, axis=0)).reshape(-1, 2)
    spacing = min(
        float(np.percentile(np.linalg.norm(np.diff(grid, axis=1), axis=-1), 10)),
        float(np.percentile(np.linalg.norm(np.diff(grid, axis=0), axis=-1), 10)),
    )
    return (
        np.arctan2(along_row[:, 1], along_row[:, 0]),
        np.arctan2(along_col[:, 1], along_col[:, 0]),
        spacing,
    )


def _model(params: FloatArray, xs: FloatArray, ys: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The blurred corner ``(N, P)`` at pixels and its Jacobian ``(N, P, 7)``."""
    x0, y0, a1, a2, s, m, amp = (params[:, k : k + 1] for k in range(7))
    dx, dy = xs - x0, ys - y0
    s1, c1, s2, c2 = np.sin(a1), np.cos(a1), np.sin(a2), np.cos(a2)
    d1, d2 = -dx * s1 + dy * c1, -dx * s2 + dy * c2
    e1, e2 = erf(d1 / (_SQRT2 * s)), erf(d2 / (_SQRT2 * s))
    g1 = np.sqrt(2 / np.pi) / s * np.exp(-0.5 * (d1 / s) ** 2)
    g2 = np.sqrt(2 / np.pi) / s * np.exp(-0.5 * (d2 / s) ** 2)
    jac = np.empty((*xs.shape, 7))
    jac[..., 0] = amp * (g1 * s1 * e2 + e1 * g2 * s2)
    jac[..., 1] = -amp * (g1 * c1 * e2 + e1 * g2 * c2)
    jac[..., 2] = amp * g1 * e2 * (-dx * c1 - dy * s1)
    jac[..., 3] = amp * e1 * g2 * (-dx * c2 - dy * s2)
    jac[..., 4] = -amp * (g1 * d1 * e2 + e1 * g2 * d2) / s
    jac[..., 5] = 1.0
    jac[..., 6] = e1 * e2
    return m + amp * e1 * e2, jac


def _windows(
    grey: FloatArray, corners: FloatArray, half: int
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Pixel coordinates, values and weights (0 off the image) of each corner's window."""
    h, w = grey.shape
    off = np.arange(-half, half + 1, dtype=np.float64)
    oy, ox = np.meshgrid(off, off, indexing="ij")
    centre = np.rint(corners)
    xs = centre[:, 0:1] + ox.ravel()[None]
    ys = centre[:, 1:2] + oy.ravel()[None]
    inside = (xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)
    values = grey[np.clip(ys, 0, h - 1).astype(np.intp), np.clip(xs, 0, w - 1).astype(np.intp)]
    return xs, ys, values, inside.astype(np.float64)


def _initial(
    corners: FloatArray,
    a1: FloatArray,
    a2: FloatArray,
    xs: FloatArray,
    ys: FloatArray,
    values: FloatArray,
    weight: FloatArray,
) -> FloatArray:
    params = np.column_stack([corners, a1, a2, np.ones(len(corners)), np.zeros((len(corners), 2))])
    _, jac = _model(params, xs, ys)
    basis = jac[..., 6]  # e1 * e2: solve the level and the amplitude linearly
    sw = weight.sum(1)
    mb, mv = (basis * weight).sum(1) / sw, (values * weight).sum(1) / sw
    cov = ((basis - mb[:, None]) * (values - mv[:, None]) * weight).sum(1)
    var = (((basis - mb[:, None]) ** 2) * weight).sum(1)
    amp = cov / np.maximum(var, 1e-12)
    params[:, 5], params[:, 6] = mv - amp * mb, amp
    return params


def refine_corners(grey: FloatArray, corners: FloatArray, board: Checkerboard) -> Corners:
    """Fit a blurred corner at each of ``corners`` (the board's order); see the module's notes.

    A corner whose fit moves it by more than 1.5 px, or does not converge, keeps NaN.
    """
    a1, a2, spacing = _grid_directions(corners, board)
    half = int(np.clip(0.4 * spacing - 1, 3, 10))
    xs, ys, values, weight = _windows(grey, corners, half)
    params = _initial(corners, a1, a2, xs, ys, values, weight)
    eye = np.eye(7)
    for _ in range(_ITERATIONS):
        model, jac = _model(params, xs, ys)
        jw = jac * weight[..., None]
        normal = np.einsum("npi,npj->nij", jw, jac)
        grad = np.einsum("npi,np->ni", jw, values - model)
        damped = normal + 1e-6 * normal * eye
        step = np.einsum("nij,nj->ni", np.linalg.pinv(damped), grad)
        params += step
        params[:, 4] = np.clip(params[:, 4], 0.3, half / 2)
    model, jac = _model(params, xs, ys)
    dof = np.maximum(weight.sum(1) - 7, 1)
    noise_var = (((values - model) ** 2) * weight).sum(1) / dof
    normal = np.einsum("npi,npj->nij", jac * weight[..., None], jac)
    cov = np.linalg.pinv(normal)[:, :2, :2] * noise_var[:, None, None]
    sigma = np.sqrt(0.5 * (cov[:, 0, 0] + cov[:, 1, 1]))
    moved = np.linalg.norm(params[:, :2] - corners, axis=1)
    bad = ~(moved < 1.5) | ~np.isfinite(sigma) | (np.abs(step[:, :2]).max(axis=1) > 1e-3)
    pixels = params[:, :2].copy()
    pixels[bad] = np.nan
    sigma[bad] = np.nan
    return Corners(pixels, sigma, np.abs(params[:, 4]))


def detect(
    image: NDArray[np.generic], board: Checkerboard, *, bayer: str | None = None
) -> Corners | None:
    """The board's refined corners in one image, or None when the board is not found whole."""
    grey = grey_image(image, bayer)
    coarse = find_corners(grey, board)
    if coarse is None:
        return None
    return refine_corners(grey, coarse, board)
