"""OpenCV's rational lens model, and rotations as vectors.

A point ``(X, Y, Z)`` in a camera's frame (+z forward, +x right, +y down) projects to
``x = X / Z``, ``y = Y / Z``, is distorted by

``x' = x q + 2 p1 x y + p2 (r^2 + 2 x^2)``, ``y' = y q + p1 (r^2 + 2 y^2) + 2 p2 x y`` with
``q = (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)``

and lands at pixel ``(fx x' + cx, fy y' + cy)``, with (0, 0) at the centre of the first
pixel, as OpenCV's ``projectPoints`` with the coefficients
``(k1, k2, p1, p2, k3, k4, k5, k6)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from elphel_host.calibrate.residual_grid import ResidualGrid

FloatArray = NDArray[np.float64]

#: Names of the rational model's coefficients, in OpenCV's order.
COEFFICIENTS = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")


def distort(x: FloatArray, y: FloatArray, coeffs: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Distorted normalised coordinates; ``coeffs`` (8,) or broadcastable ``(..., 8)`` rows."""
    c = np.asarray(coeffs, dtype=np.float64)
    k1, k2, p1, p2, k3, k4, k5, k6 = (c[..., i] for i in range(8))
    r2 = x * x + y * y
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return xd, yd


def undistort(
    xd: FloatArray, yd: FloatArray, coeffs: FloatArray, *, iterations: int = 40, strict: bool = True
) -> tuple[FloatArray, FloatArray]:
    """Normalised coordinates whose distortion is ``(xd, yd)`` (Newton's method).

    Where the model does not invert (more than 1e-9 left): ValueError when ``strict``,
    NaN otherwise (a fitted model may fold far from its data, in the image's corners).
    """
    x, y = np.array(xd, dtype=np.float64), np.array(yd, dtype=np.float64)
    h = 1e-7
    for _ in range(iterations):
        fx, fy = distort(x, y, coeffs)
        ex, ey = fx - xd, fy - yd
        if max(float(np.max(np.abs(ex), initial=0)), float(np.max(np.abs(ey), initial=0))) < 1e-12:
            break
        ax, ay = distort(x + h, y, coeffs)
        bx, by = distort(x, y + h, coeffs)
        j11, j21 = (ax - fx) / h, (ay - fy) / h
        j12, j22 = (bx - fx) / h, (by - fy) / h
        det = j11 * j22 - j12 * j21
        x = x - (j22 * ex - j12 * ey) / det
        y = y - (-j21 * ex + j11 * ey) / det
    fx, fy = distort(x, y, coeffs)
    left = np.hypot(fx - xd, fy - yd)
    if not strict:
        bad = ~(left < 1e-9)
        return np.where(bad, np.nan, x), np.where(bad, np.nan, y)
    worst = float(np.max(left, initial=0.0))
    if not worst < 1e-9:
        raise ValueError(
            f"the lens model does not invert at some points ({worst:.2g} left); "
            "allowed: distortion coefficients whose mapping is monotonic over the image"
        )
    return x, y


@dataclass(frozen=True)
class CameraModel:
    """One camera's intrinsics: pinhole plus OpenCV's rational distortion (8 coefficients).

    ``residual``, when the solve found one, is added to every projected pixel
    (`residual_grid`): the lens's smooth error the rational model cannot follow.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = (0.0,) * 8
    residual: ResidualGrid | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if len(self.distortion) != 8:
            raise ValueError(
                f"distortion has {len(self.distortion)} coefficients; allowed: 8 "
                f"({', '.join(COEFFICIENTS)})"
            )
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"image {self.width}x{self.height}; allowed: positive sizes")

    @property
    def camera_matrix(self) -> FloatArray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def coefficients(self) -> FloatArray:
        return np.array(self.distortion, dtype=np.float64)

    def project(self, points: FloatArray) -> FloatArray:
        """Pixels ``(N, 2)`` of points ``(N, 3)`` in the camera's frame."""
        p = np.asarray(points, dtype=np.float64)
        xd, yd = distort(p[:, 0] / p[:, 2], p[:, 1] / p[:, 2], self.coefficients)
        return self.add_residual(np.stack([self.fx * xd + self.cx, self.fy * yd + self.cy], axis=1))

    def add_residual(self, pixels: FloatArray) -> FloatArray:
        """Pixels ``(N, 2)`` of the rational model moved by the residual grid, if any."""
        if self.residual is None:
            return pixels
        out: FloatArray = pixels + self.residual.at(pixels)
        return out

    def remove_residual(self, pixels: FloatArray) -> FloatArray:
        """The rational model's pixels ``(N, 2)`` that the residual moves to ``pixels``.

        Fixed-point iteration: the residual changes by far less than a pixel per pixel,
        so each round shrinks the error by that slope.
        """
        if self.residual is None:
            return pixels
        q = np.array(pixels, dtype=np.float64)
        for _ in range(6):
            q = pixels - self.residual.at(q)
        return q

    def rays(self, pixels: FloatArray, *, strict: bool = True) -> FloatArray:
        """Normalised undistorted coordinates ``(N, 2)`` (``x = X/Z``) of pixels ``(N, 2)``.

        ``strict``: see `undistort` (False: NaN where the model folds).
        """
        q = self.remove_residual(np.asarray(pixels, dtype=np.float64))
        x, y = undistort(
            (q[:, 0] - self.cx) / self.fx,
            (q[:, 1] - self.cy) / self.fy,
            self.coefficients,
            strict=strict,
        )
        return np.stack([x, y], axis=1)

    @classmethod
    def from_vector(cls, width: int, height: int, values: FloatArray) -> CameraModel:
        """A model from ``(fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6)``."""
        v = [float(x) for x in values]
        if len(v) != 12:
            raise ValueError(
                f"{len(v)} intrinsic values; allowed: 12 (fx fy cx cy and 8 coefficients)"
            )
        return cls(width, height, v[0], v[1], v[2], v[3], tuple(v[4:]))

    def to_json(self) -> dict[str, object]:
        out: dict[str, object] = {
            "width": self.width,
            "height": self.height,
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "distortion": {"model": "opencv", "coefficients": list(self.distortion)},
        }
        if self.residual is not None:
            out["residual_grid"] = self.residual.to_json()
        return out

    @classmethod
    def from_json(cls, data: dict[str, object]) -> CameraModel:
        dist = data["distortion"]
        if not isinstance(dist, dict) or dist.get("model") != "opencv":
            raise ValueError(f"distortion {dist!r}; allowed: {{'model': 'opencv', ...}}")
        coeffs = [float(c) for c in dist["coefficients"]]
        coeffs += [0.0] * max(0, 8 - len(coeffs))
        if any(coeffs[8:]):
            raise ValueError("distortion: thin-prism terms (s1..s4) are not supported; allowed: 8")
        width, height = int(data["width"]), int(data["height"])  # type: ignore[call-overload]
        grid = data.get("residual_grid")
        return cls(
            width,
            height,
            float(data["fx"]),  # type: ignore[arg-type]
            float(data["fy"]),  # type: ignore[arg-type]
            float(data["cx"]),  # type: ignore[arg-type]
            float(data["cy"]),  # type: ignore[arg-type]
            tuple(coeffs[:8]),
            None if grid is None else ResidualGrid.from_json(width, height, grid),
        )


def rotation_matrix(rvec: FloatArray) -> FloatArray:
    """Rotation matrices ``(..., 3, 3)`` of rotation vectors ``(..., 3)`` (Rodrigues)."""
    r = np.asarray(rvec, dtype=np.float64)
    theta = np.linalg.norm(r, axis=-1)[..., None, None]
    k = np.zeros((*r.shape[:-1], 3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -r[..., 2], r[..., 1], -r[..., 0]
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = r[..., 2], -r[..., 1], r[..., 0]
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24, (1 - np.cos(safe)) / safe**2)
    out: FloatArray = np.eye(3) + a * k + b * (k @ k)
    return out


def rotation_vector(matrix: FloatArray) -> FloatArray:
    """The rotation vector ``(3,)`` of a rotation matrix ``(3, 3)``."""
    m = np.asarray(matrix, dtype=np.float64)
    cos = np.clip((np.trace(m) - 1) / 2, -1.0, 1.0)
    theta = float(np.arccos(cos))
    axis = np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]])
    if theta < 1e-8:
        return axis / 2
    if np.pi - theta < 1e-6:
        _, v = np.linalg.eigh((m + np.eye(3)) / 2)
        return v[:, -1] * theta
    out: FloatArray = axis * theta / (2 * np.sin(theta))
    return out
