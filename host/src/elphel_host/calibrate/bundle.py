"""The joint bundle adjustment: intrinsics, rig, board poses and board bend in one solve.

Parameters: per camera ``fx, fy, cx, cy`` and the rational model's 8 coefficients; per
camera after camera 0 its pose from camera 0 (rotation vector, translation in mm); per
view the board's pose in camera 0's frame; the board's bend ``(wx, wy)`` in mm (mrcal's:
``z = wx (1 - X^2) + wy (1 - Y^2)``, X and Y scaled to -1..1 over the inner corners);
with ``grid_cells``, per camera the controls of its residual grid (`residual_grid`),
added to the rational model's pixels.
Residuals are each corner's reprojection error divided by its detected uncertainty.
Levenberg-Marquardt solves it; the Jacobian comes from central differences in 26 groups
(a corner depends on its camera, its view and the bend only, so one evaluation perturbs
the same parameter of every camera, or of every board, at once), and exactly for the
residual grids' controls, on which the pixels depend linearly.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy import sparse

from elphel_host.calibrate.camera_model import CameraModel, distort, rotation_matrix
from elphel_host.calibrate.initial import InitialGuess, pose_vector
from elphel_host.calibrate.pattern import Checkerboard
from elphel_host.calibrate.residual_grid import ResidualGrid

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

INTRINSICS = 12
POSE = 6
WARP = 2
#: Smallest corner uncertainty used as a weight (px): no corner outweighs the rest by far.
MIN_SIGMA_PX = 0.002
#: Standard deviation of the prior on the rational model's k4, k5, k6.
PRIOR_RATIONAL = 0.05
#: Residual grid priors (px): its controls' size, their second differences along a row or
#: a column (smoothness where corners are few), and the grid's mean and tilt, which the
#: principal point, focal lengths and the camera's pose already hold.
PRIOR_GRID_PX = 1.0
PRIOR_GRID_CURVE_PX = 0.05
PRIOR_GRID_GAUGE_PX = 1e-4


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
    grid_cells: tuple[int, int] | None = None

    @property
    def cameras(self) -> int:
        return len(self.sizes)

    @property
    def grid_controls(self) -> int:
        """Residual-grid parameters per camera (0 without a grid)."""
        if self.grid_cells is None:
            return 0
        return (self.grid_cells[0] + 3) * (self.grid_cells[1] + 3) * 2

    @property
    def parameters(self) -> int:
        c = self.cameras
        return c * INTRINSICS + (c - 1) * POSE + self.views * POSE + WARP + c * self.grid_controls

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
            self.grid_cells,
        )

    def with_grid(self, cells: tuple[int, int] | None) -> Problem:
        return replace(self, grid_cells=cells)


@dataclass(frozen=True)
class Unpacked:
    """The parameter vector by meaning."""

    intrinsics: FloatArray  # (cameras, 12): fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6
    rig: FloatArray  # (cameras, 6), camera 0's zero
    boards: FloatArray  # (views, 6)
    warp_mm: FloatArray  # (2,)
    grids: FloatArray  # (cameras, grid_controls): each camera's controls, flat


def unpack(x: FloatArray, problem: Problem) -> Unpacked:
    cameras, views = problem.cameras, problem.views
    n_i = cameras * INTRINSICS
    n_r = (cameras - 1) * POSE
    n_b = n_i + n_r + views * POSE
    rig = np.zeros((cameras, POSE))
    rig[1:] = x[n_i : n_i + n_r].reshape(-1, POSE)
    boards = x[n_i + n_r : n_b].reshape(views, POSE)
    grids = x[n_b + WARP :].reshape(cameras, problem.grid_controls)
    return Unpacked(x[:n_i].reshape(cameras, INTRINSICS), rig, boards, x[n_b : n_b + WARP], grids)


def pack(guess: InitialGuess) -> FloatArray:
    intr = [[m.fx, m.fy, m.cx, m.cy, *m.distortion] for m in guess.lenses]
    rig = [pose_vector(p) for p in guess.rig[1:]]
    boards = [pose_vector(p) for p in guess.boards]
    parts = [np.ravel(intr), np.ravel(rig), np.ravel(boards), np.zeros(WARP)]
    return np.concatenate(parts)


def add_zero_grids(x: FloatArray, problem: Problem, cells: tuple[int, int]) -> FloatArray:
    """``x`` of a solve without grids extended by zero grids of ``cells`` per camera."""
    if problem.grid_cells is not None:
        raise ValueError("the solve already has residual grids")
    controls = (cells[0] + 3) * (cells[1] + 3) * 2
    return np.concatenate([x, np.zeros(problem.cameras * controls)])


def grid_of(x: FloatArray, problem: Problem, camera: int) -> ResidualGrid | None:
    """Camera ``camera``'s solved residual grid (None without grids)."""
    if problem.grid_cells is None:
        return None
    cx, cy = problem.grid_cells
    w, h = problem.sizes[camera]
    controls = unpack(x, problem).grids[camera].reshape(cy + 3, cx + 3, 2)
    return ResidualGrid(w, h, controls.copy())


def board_points(pattern: Checkerboard, warp_mm: FloatArray) -> FloatArray:
    """The corners ``(N, 3)`` of the bent board in its own frame."""
    pts = pattern.object_points_mm()
    xs = 2 * pts[:, 0] / ((pattern.cols - 1) * pattern.square_mm) - 1
    ys = 2 * pts[:, 1] / ((pattern.rows - 1) * pattern.square_mm) - 1
    pts[:, 2] = warp_mm[0] * (1 - xs**2) + warp_mm[1] * (1 - ys**2)
    return pts


def project(x: FloatArray, problem: Problem) -> FloatArray:
    """The predicted pixel ``(M, 2)`` of every corner row of ``problem``."""
    p = unpack(x, problem)
    pixels = _model_pixels(p, problem)
    if problem.grid_cells is None:
        return pixels
    index, weight = _grid_basis(pixels, problem)
    flat = p.grids.reshape(-1, 2)  # every camera's controls, one after another
    out: FloatArray = pixels + np.einsum("nk,nkc->nc", weight, flat[index])
    return out


def _model_pixels(p: Unpacked, problem: Problem) -> FloatArray:
    """The rational model's pixels ``(M, 2)`` of every corner row, before any grid."""
    pts = board_points(problem.pattern, p.warp_mm)[problem.corner]
    rb = rotation_matrix(p.boards[:, :3])[problem.view]
    x0 = np.einsum("mij,mj->mi", rb, pts) + p.boards[problem.view, 3:]
    rc = rotation_matrix(p.rig[:, :3])[problem.camera]
    xc = np.einsum("mij,mj->mi", rc, x0) + p.rig[problem.camera, 3:]
    intr = p.intrinsics[problem.camera]
    xd, yd = distort(xc[:, 0] / xc[:, 2], xc[:, 1] / xc[:, 2], intr[:, 4:])
    out: FloatArray = np.column_stack([intr[:, 0] * xd + intr[:, 2], intr[:, 1] * yd + intr[:, 3]])
    return out


def _grid_basis(pixels: FloatArray, problem: Problem) -> tuple[IntArray, FloatArray]:
    """Each row's 16 controls (indices into all cameras' controls, flat) and weights."""
    assert problem.grid_cells is not None
    per_camera = problem.grid_controls // 2
    index = np.zeros((len(pixels), 16), dtype=np.intp)
    weight = np.zeros((len(pixels), 16))
    for c, (w, h) in enumerate(problem.sizes):
        rows = problem.camera == c
        grid = ResidualGrid.zeros(w, h, problem.grid_cells)
        i, wt = grid.basis(pixels[rows])
        index[rows], weight[rows] = i + c * per_camera, wt
    return index, weight


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
    """The whitened residuals' Jacobian ``(2 M, parameters)``.

    Central differences for the model's parameters; the residual grids' columns exactly
    (a pixel moves by each control's spline weight, along the control's axis).
    """
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
    if problem.grid_cells is not None:
        _grid_columns(out, x, problem)
    return out


def _grid_columns(out: FloatArray, x: FloatArray, problem: Problem) -> None:
    """Fill the residual grids' columns of the Jacobian ``out`` in place."""
    start = problem.parameters - problem.cameras * problem.grid_controls
    pixels = _model_pixels(unpack(x, problem), problem)
    index, weight = _grid_basis(pixels, problem)
    whiten = 1.0 / np.maximum(problem.sigma_px, MIN_SIGMA_PX)
    m = np.arange(len(pixels))[:, None]
    for axis in (0, 1):
        out[2 * m + axis, start + 2 * index + axis] = weight * whiten[:, None]


def normal_equations(jac: FloatArray, res: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``J^T J`` and ``J^T r``, through J's sparsity.

    A corner row touches its camera, its view, the bend and 16 grid controls: some 40 of
    the hundreds of columns, so the sparse product is far cheaper than the dense one.
    """
    sp = sparse.csr_matrix(jac)
    jtj: FloatArray = (sp.T @ sp).toarray()
    jtr: FloatArray = sp.T @ res
    return jtj, jtr


def prior_matrix(problem: Problem) -> FloatArray:
    """The quadratic prior ``P`` (cost ``x^T P x``) on the parameters.

    * The rational model's k4..k6, ``1 / PRIOR_RATIONAL^2`` each: its numerator and
      denominator trade against each other along a long flat valley the data barely
      constrains; this weak pull keeps k4..k6 near zero unless the corners need them, and
      keeps the model from folding outside its data.
    * Each residual grid (`grid_prior`).
    """
    n = problem.parameters
    out = np.zeros((n, n))
    for c in range(problem.cameras):
        k = np.arange(c * INTRINSICS + 9, c * INTRINSICS + 12)
        out[k, k] = 1.0 / PRIOR_RATIONAL**2
    if problem.grid_cells is not None:
        block = grid_prior(problem.grid_cells)
        start = n - problem.cameras * problem.grid_controls
        for c in range(problem.cameras):
            s = slice(start + c * len(block), start + (c + 1) * len(block))
            out[s, s] = block
    return out


def grid_prior(cells: tuple[int, int]) -> FloatArray:
    """One camera's residual-grid prior over its controls (x and y interleaved).

    A weak pull to zero (``PRIOR_GRID_PX``), so the rational model keeps what it can
    express; second differences along rows and columns (``PRIOR_GRID_CURVE_PX``), so the
    grid stays smooth where few corners fall; and its mean and tilt over the image held
    at zero (``PRIOR_GRID_GAUGE_PX``): a shift or a tilt is the principal point, the
    focal lengths or the camera's roll, which the model already has.
    """
    cx, cy = cells
    nx, ny = cx + 3, cy + 3
    eye_x, eye_y = np.eye(nx), np.eye(ny)
    d2x = np.kron(eye_y, np.diff(eye_x, 2, axis=0))
    d2y = np.kron(np.diff(eye_y, 2, axis=0), eye_x)
    gx, gy = np.meshgrid(np.linspace(-1, 1, nx), np.linspace(-1, 1, ny))
    fit = np.linalg.pinv(np.column_stack([np.ones(nx * ny), gx.ravel(), gy.ravel()]))
    one_axis = (
        np.eye(nx * ny) / PRIOR_GRID_PX**2
        + (d2x.T @ d2x + d2y.T @ d2y) / PRIOR_GRID_CURVE_PX**2
        + fit.T @ fit / PRIOR_GRID_GAUGE_PX**2
    )
    out: FloatArray = np.kron(one_axis, np.eye(2)).astype(np.float64)
    return out


def adjust(
    x0: FloatArray, problem: Problem, *, iterations: int = 100
) -> tuple[FloatArray, FloatArray]:
    """Levenberg-Marquardt: the solved parameters and the Jacobian there.

    The normal equations are Jacobi-scaled (each parameter by its column's norm, the
    prior's diagonal included), the prior (`prior_matrix`) added, and damped by
    ``lambda`` times their diagonal; the loop ends when a step lowers the cost by less
    than a part in 1e8.
    """
    groups = _column_groups(problem)
    prior = prior_matrix(problem)
    x = x0.copy()
    res = residuals(x, problem)
    cost = float(res @ res + x @ prior @ x)
    lam = 1e-3
    for _ in range(iterations):
        jtj, jtr = normal_equations(jacobian(x, problem, groups), res)
        scale = np.maximum(np.sqrt(np.diag(jtj) + np.diag(prior)), 1e-12)
        normal = (jtj + prior) / np.outer(scale, scale)
        grad = (jtr + prior @ x) / scale
        while lam < 1e12:
            step = np.linalg.solve(normal + lam * np.diag(np.diag(normal)), -grad) / scale
            trial = residuals(x + step, problem)
            trial_cost = float(trial @ trial + (x + step) @ prior @ (x + step))
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
    """Camera ``camera``'s solved intrinsics, with its residual grid when solved with one."""
    intr = unpack(x, problem).intrinsics[camera]
    w, h = problem.sizes[camera]
    return replace(CameraModel.from_vector(w, h, intr), residual=grid_of(x, problem, camera))
