"""How good a calibration is: projection difference, projection uncertainty.

mrcal's measures. The *projection difference* of two models of one lens: rays of a grid
of pixels through the first model are turned by the rotation that best aligns them with
the second model's rays (a rotation the data cannot tell from a turned camera), then
projected by the second; the distance to the starting pixels is the difference. The
*projection uncertainty* of a pixel is the standard deviation of where the solve could
have put a point seen there, from the intrinsics' covariance (the solve's Jacobian and
its residual noise).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from elphel_host.calibrate.camera_model import CameraModel

FloatArray = NDArray[np.float64]


class Lens(Protocol):
    """What the projection difference needs of a lens model."""

    @property
    def width(self) -> int: ...

    @property
    def height(self) -> int: ...

    def project(self, points: FloatArray) -> FloatArray: ...

    def rays(self, pixels: FloatArray, *, strict: bool = True) -> FloatArray: ...


def pixel_grid(width: int, height: int, *, step_px: float, margin: float = 0.0) -> FloatArray:
    """Pixels ``(N, 2)`` on a grid ``step_px`` apart, ``margin`` (fraction) in from the edges."""
    xs = np.arange(margin * width, (1 - margin) * width - 0.5, step_px)
    ys = np.arange(margin * height, (1 - margin) * height - 0.5, step_px)
    gx, gy = np.meshgrid(xs, ys)
    return np.column_stack([gx.ravel(), gy.ravel()])


def _unit(rays: FloatArray) -> FloatArray:
    v = np.column_stack([rays, np.ones(len(rays))])
    out: FloatArray = v / np.linalg.norm(v, axis=1, keepdims=True)
    return out


def implied_rotation(
    a: Lens, b: Lens, *, step_px: float = 16.0, margin: float = 0.05
) -> FloatArray:
    """The rotation ``(3, 3)`` that best turns ``a``'s rays into ``b``'s over `pixel_grid`."""
    pixels = pixel_grid(a.width, a.height, step_px=step_px, margin=margin)
    va, vb = _unit(a.rays(pixels, strict=False)), _unit(b.rays(pixels, strict=False))
    ok = np.isfinite(va).all(axis=1) & np.isfinite(vb).all(axis=1)
    u, _, vt = np.linalg.svd(vb[ok].T @ va[ok])
    out: FloatArray = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt  # Kabsch
    return out


def projection_difference(
    a: Lens, b: Lens, *, step_px: float = 16.0, margin: float = 0.05
) -> FloatArray:
    """Per-pixel difference ``(N,)`` in px on `pixel_grid` after the implied rotation.

    ``margin``: the border left out (a fraction of each side; corners are extrapolated
    far from any observation in most data sets). NaN where either model folds.
    """
    pixels = pixel_grid(a.width, a.height, step_px=step_px, margin=margin)
    va = _unit(a.rays(pixels, strict=False))
    ok = np.isfinite(va).all(axis=1)
    moved = va @ implied_rotation(a, b, step_px=step_px, margin=margin).T
    out: FloatArray = np.full(len(pixels), np.nan)
    out[ok] = np.linalg.norm(b.project(moved[ok]) - pixels[ok], axis=1)
    return out


def projection_jacobian(lens: CameraModel, pixels: FloatArray, distance_mm: float) -> FloatArray:
    """d(pixel)/d(intrinsics) ``(N, 2, 12)`` for points seen at ``pixels`` at ``distance_mm``.

    NaN where the model folds.
    """
    rays = lens.rays(pixels, strict=False)
    points = np.column_stack([rays, np.ones(len(rays))]) * distance_mm
    base = np.array([lens.fx, lens.fy, lens.cx, lens.cy, *lens.distortion])
    out = np.empty((len(pixels), 2, len(base)))
    for k in range(len(base)):
        h = 1e-6 * max(abs(base[k]), 1e-3)
        hi, lo = base.copy(), base.copy()
        hi[k] += h
        lo[k] -= h
        ph = CameraModel.from_vector(lens.width, lens.height, hi).project(points)
        pl = CameraModel.from_vector(lens.width, lens.height, lo).project(points)
        out[:, :, k] = (ph - pl) / (2 * h)
    return out


def _rotation_jacobian(lens: CameraModel, points: FloatArray) -> FloatArray:
    """d(pixel)/d(small camera rotation) ``(N, 2, 3)``."""
    out = np.empty((len(points), 2, 3))
    h = 1e-7
    for k in range(3):
        w = np.zeros(3)
        w[k] = h
        out[:, :, k] = (
            lens.project(points + np.cross(w, points)) - lens.project(points - np.cross(w, points))
        ) / (2 * h)
    return out


def projection_uncertainty(
    lens: CameraModel, covariance: FloatArray, pixels: FloatArray, *, distance_mm: float
) -> FloatArray:
    """Standard deviation per axis ``(N,)`` (px, RMS of x and y) of each pixel's projection.

    As the projection difference does, it leaves out what a small rotation of the camera
    explains: each intrinsic parameter's effect over ``pixels`` is stripped of its best
    fitting rotation before the covariance propagates through it.
    """
    jac = projection_jacobian(lens, pixels, distance_mm)
    ok = np.isfinite(jac).all(axis=(1, 2))
    rays = lens.rays(pixels[ok], strict=False)
    points = np.column_stack([rays, np.ones(len(rays))]) * distance_mm
    rot = _rotation_jacobian(lens, points).reshape(-1, 3)
    flat = jac[ok].reshape(-1, jac.shape[2])
    coef, *_ = np.linalg.lstsq(rot, flat, rcond=None)
    stripped = (flat - rot @ coef).reshape(-1, 2, jac.shape[2])
    cov = np.einsum("nik,kl,njl->nij", stripped, covariance, stripped)
    out: FloatArray = np.full(len(pixels), np.nan)
    out[ok] = np.sqrt(np.maximum(0.5 * (cov[:, 0, 0] + cov[:, 1, 1]), 0.0))
    return out


def grid_shape(width: int, height: int, *, step_px: float, margin: float = 0.0) -> tuple[int, int]:
    """(rows, cols) of `pixel_grid`."""
    xs = np.arange(margin * width, (1 - margin) * width - 0.5, step_px)
    ys = np.arange(margin * height, (1 - margin) * height - 0.5, step_px)
    return len(ys), len(xs)


def covered(pixels: FloatArray, observed: FloatArray, *, radius_px: float) -> NDArray[np.bool_]:
    """Which ``pixels`` lie within ``radius_px`` of an observed corner (the data's region)."""
    if len(observed) == 0:
        return np.zeros(len(pixels), dtype=bool)
    dist, _ = cKDTree(observed).query(pixels)
    out: NDArray[np.bool_] = dist <= radius_px
    return out
