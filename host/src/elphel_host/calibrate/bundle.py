"""The joint bundle adjustment: intrinsics, rig, board poses and board bend in one solve.

Parameters: per camera ``fx, fy, cx, cy`` and the rational model's 8 coefficients; per
camera after camera 0 its pose from camera 0 (rotation vector, translation in mm); per
view the board's pose in camera 0's frame; the board's bend ``(wx, wy)`` in mm (mrcal's:
``z = wx (1 - X^2) + wy (1 - Y^2)``, X and Y scaled to -1..1 over the inner corners).
Residuals are each corner's reprojection error divided by its detected uncertainty.
Levenberg-Marquardt solves it; the Jacobian comes from central differences in 26 groups
(a corner depends on its camera, its view and the bend only, so one evaluation perturbs
the same parameter of every camera, or of every board, at once).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from elphel_host.calibrate.camera_model import CameraModel, distort, rotation_matrix
from elphel_host.calibrate.initial import InitialGuess, pose_vector
from elphel_host.calibrate.pattern import Checkerboard

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

INTRINSICS = 12
POSE = 6
WARP = 2
#: Smallest corner uncertainty used as a weight (px): no corner outweighs the rest by far.
MIN_SIGMA_PX = 0.002
#: Standard deviation of the prior on the rational model's k4, k5, k6.
PRIOR_RATIONAL = 0.05


@dataclass(frozen=True)
class Problem:
    """The corners the solve fits: one row per corner seen by one camera in one view."""

    pattern: Checkerboard
    sizes: tuple[tuple[int, int], ...]
    views: int
    camera: IntArray
    view: IntArray
    corner: IntArray
    pixels: FloatArray
    sigma_px: FloatArray

    @property
    def cameras(self) -> int:
        return len(self.sizes)

    @property
    def parameters(self) -> int:
        return self.cameras * INTRINSICS + (self.cameras - 1) * POSE + self.views * POSE + WARP

    def keep(self, rows: NDArray[np.bool_]) -> Problem:
        return Problem(
            self.pattern,
            self.sizes,
            self.views,
            self.camera[rows],
            self.view[rows],
            self.corner[rows],
            self.pixels[rows],
            self.sigma_px[rows],
        )


@dataclass(frozen=True)
class Unpacked:
    """The parameter vector by meaning."""

    intrinsics: FloatArray  # (cameras, 12): fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6
    rig: FloatArray  # (cameras, 6), camera 0's zero
    boards: FloatArray  # (views, 6)
    warp_mm: FloatArray  # (2,)


def unpack(x: FloatArray, cameras: int, views: int) -> Unpacked:
    n_i = cameras * INTRINSICS
    n_r = (cameras - 1) * POSE
    rig = np.zeros((cameras, POSE))
    rig[1:] = x[n_i : n_i + n_r].reshape(-1, POSE)
    boards = x[n_i + n_r : n_i + n_r + views * POSE].reshape(views, POSE)
    return Unpacked(x[:n_i].reshape(cameras, INTRINSICS), rig, boards, x[-WARP:])


def pack(guess: InitialGuess) -> FloatArray:
    intr = [[m.fx, m.fy, m.cx, m.cy, *m.distortion] for m in guess.lenses]
    rig = [pose_vector(p) for p in guess.rig[1:]]
    boards = [pose_vector(p) for p in guess.boards]
    parts = [np.ravel(intr), np.ravel(rig), np.ravel(boards), np.zeros(WARP)]
    return np.concatenate(parts)


def board_points(pattern: Checkerboard, warp_mm: FloatArray) -> FloatArray:
    """The corners ``(N, 3)`` of the bent board in its own frame."""
    pts = pattern.object_points_mm()
    xs = 2 * pts[:, 0] / ((pattern.cols - 1) * pattern.square_mm) - 1
    ys = 2 * pts[:, 1] / ((pattern.rows - 1) * pattern.square_mm) - 1
    pts[:, 2] = warp_mm[0] * (1 - xs**2) + warp_mm[1] * (1 - ys**2)
    return pts


def project(x: FloatArray, problem: Problem) -> FloatArray:
    """The predicted pixel ``(M, 2)`` of every corner row of ``problem``."""
    p = unpack(x, problem.cameras, problem.views)
    pts = board_points(problem.pattern, p.warp_mm)[problem.corner]
    rb = rotation_matrix(p.boards[:, :3])[problem.view]
    x0 = np.einsum("mij,mj->mi", rb, pts) + p.boards[problem.view, 3:]
    rc = rotation_matrix(p.rig[:, :3])[problem.camera]
    xc = np.einsum("mij,mj->mi", rc, x0) + p.rig[problem.camera, 3:]
    intr = p.intrinsics[problem.camera]
    xd, yd = distort(xc[:, 0] / xc[:, 2], xc[:, 1] / xc[:, 2], intr[:, 4:])
    return np.column_stack([intr[:, 0] * xd + intr[:, 2], intr[:, 1] * yd + intr[:, 3]])


def residuals(x: FloatArray, problem: Problem) -> FloatArray:
    """Whitened reprojection errors, ``(2 M,)``: x and y of each corner row."""
    weight = 1.0 / np.maximum(problem.sigma_px, MIN_SIGMA_PX)
    out: FloatArray = ((project(x, problem) - problem.pixels) * weight[:, None]).ravel()
    return out


def _column_groups(problem: Problem) -> list[tuple[IntArray, IntArray]]:
    """Parameter groups perturbed together, each with the column of every residual row.

    Parameter k of every camera's intrinsics (or of every camera's pose, or of every
    board's pose) touches disjoint rows, so one evaluation gives all of their columns.
    """
    c, v = problem.cameras, problem.views
    n_i, n_r = c * INTRINSICS, (c - 1) * POSE
    rows = np.repeat(problem.camera, 2)
    views = np.repeat(problem.view, 2)
    groups = []
    for k in range(INTRINSICS):
        groups.append((np.arange(c) * INTRINSICS + k, rows * INTRINSICS + k))
    for k in range(POSE):
        if c > 1:
            groups.append(
                (
                    n_i + np.arange(c - 1) * POSE + k,
                    np.where(rows > 0, n_i + (rows - 1) * POSE + k, -1),
                )
            )
        groups.append((n_i + n_r + np.arange(v) * POSE + k, n_i + n_r + views * POSE + k))
    for k in range(WARP):
        groups.append(
            (np.array([n_i + n_r + v * POSE + k]), np.full(len(rows), n_i + n_r + v * POSE + k))
        )
    return groups


def jacobian(
    x: FloatArray, problem: Problem, groups: list[tuple[IntArray, IntArray]]
) -> FloatArray:
    """The whitened residuals' Jacobian ``(2 M, parameters)`` by central differences."""
    out = np.zeros((2 * len(problem.camera), len(x)))
    rows = np.arange(2 * len(problem.camera))
    for params, cols in groups:
        idx = params.astype(np.intp)
        h = 1e-6 * np.maximum(np.abs(x[idx]), 1e-2)
        hi, lo = x.copy(), x.copy()
        hi[idx] += h
        lo[idx] -= h
        step = np.zeros(len(x))
        step[idx] = 2 * h
        diff = residuals(hi, problem) - residuals(lo, problem)
        ok = cols >= 0
        out[rows[ok], cols[ok]] = diff[ok] / step[cols[ok]]
    return out


def prior_weights(problem: Problem) -> FloatArray:
    """Per parameter ``1 / sigma^2`` of a zero-mean prior (the rational model's k4..k6 only).

    The rational model's numerator and denominator trade against each other along a long
    flat valley the data barely constrains; this weak pull keeps k4..k6 near zero unless
    the corners need them, and keeps the model from folding outside its data.
    """
    w = np.zeros(problem.parameters)
    for c in range(problem.cameras):
        w[c * INTRINSICS + 9 : c * INTRINSICS + 12] = 1.0 / PRIOR_RATIONAL**2
    return w


def adjust(
    x0: FloatArray, problem: Problem, *, iterations: int = 100
) -> tuple[FloatArray, FloatArray]:
    """Levenberg-Marquardt: the solved parameters and the Jacobian there.

    The normal equations are Jacobi-scaled (each parameter by its column's norm), the
    prior (`prior_weights`) added, and damped by ``lambda`` times their diagonal; the
    loop ends when a step lowers the cost by less than a part in 1e8.
    """
    groups = _column_groups(problem)
    prior = prior_weights(problem)
    x = x0.copy()
    res = residuals(x, problem)
    cost = float(res @ res + prior @ x**2)
    lam = 1e-3
    for _ in range(iterations):
        jac = jacobian(x, problem, groups)
        scale = np.maximum(np.linalg.norm(jac, axis=0), 1e-12)
        js = jac / scale
        normal = js.T @ js + np.diag(prior / scale**2)
        grad = js.T @ res + prior * x / scale
        while lam < 1e12:
            step = np.linalg.solve(normal + lam * np.diag(np.diag(normal)), -grad) / scale
            trial = residuals(x + step, problem)
            trial_cost = float(trial @ trial + prior @ (x + step) ** 2)
            if np.isfinite(trial_cost) and trial_cost < cost:
                break
            lam *= 4.0
        else:
            break
        x, res, gain = x + step, trial, cost - trial_cost
        cost, lam = trial_cost, max(lam / 3.0, 1e-9)
        if gain < 1e-8 * cost:
            break
    return x, jacobian(x, problem, groups)


def lens(x: FloatArray, problem: Problem, camera: int) -> CameraModel:
    """Camera ``camera``'s solved intrinsics."""
    intr = unpack(x, problem.cameras, problem.views).intrinsics[camera]
    w, h = problem.sizes[camera]
    return CameraModel.from_vector(w, h, intr)
