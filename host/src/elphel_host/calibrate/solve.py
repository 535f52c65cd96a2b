"""The calibration: observations in, every camera's model and the rig out, with its quality.

`calibrate` checks the observations (`check_observations`), guesses (`initial_guess`),
solves the bundle adjustment (`bundle.adjust`), drops outlier corners and solves again
(a corner whose error is more than `OUTLIER_SIGMAS` times the residuals' robust spread,
the worst of each image per round),
then, unless told not to, fits each camera's residual grid on top of its rational model
and keeps the grids when the data supports them (`_fit_residual_grids`), then measures:
per-camera and per-view residuals, the intrinsics' covariance and from it
each camera's projection uncertainty, and (when asked) the cross-validation of two
halves of the views (mrcal's projection difference between their calibrations).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from elphel_host.calibrate import bundle
from elphel_host.calibrate.camera_model import CameraModel, rotation_matrix
from elphel_host.calibrate.initial import initial_guess
from elphel_host.calibrate.observations import Observations, check_observations
from elphel_host.calibrate.quality import (
    grid_shape,
    pixel_grid,
    projection_difference,
    projection_uncertainty,
)
from elphel_host.calibrate.residual_grid import DEFAULT_CELLS

FloatArray = NDArray[np.float64]

OUTLIER_SIGMAS = 5.0
#: The border (fraction of each side) the quality measures leave out, as mrcal's tools do.
MARGIN = 0.05
ROUNDS = 8
#: How the solve treats residual grids: fit and keep when supported, never, or always
#: with these ``(cells_x, cells_y)``.
GridOption = Literal["auto", "off"] | tuple[int, int]


@dataclass(frozen=True)
class Outlier:
    """A corner left out of the solve: its view, camera, corner index and error (px)."""

    view: str
    camera: int
    corner: int
    error_px: float


@dataclass(frozen=True)
class CameraResult:
    """One camera's solved model, pose from camera 0 and quality."""

    lens: CameraModel
    R: FloatArray
    t_mm: FloatArray
    rms_px: float
    corners: int
    uncertainty_px: float  # RMS over the image of the projection uncertainty
    uncertainty_map: FloatArray  # (rows, cols) on `pixel_grid` with MARGIN
    residuals: FloatArray  # (N, 4): x, y, dx, dy of every corner used


@dataclass(frozen=True)
class Calibration:
    """The solve's result; `result.write_calibration` writes it (docs/calibration.md)."""

    pattern: str
    rms_px: float
    cameras: tuple[CameraResult, ...]
    views: tuple[dict[str, object], ...]
    warp_mm: tuple[float, float]
    outliers: tuple[Outlier, ...]
    missing: tuple[tuple[str, int], ...]
    warnings: tuple[str, ...]
    residual_grid: dict[str, object]
    cross_validation: dict[str, object] | None = None


def make_problem(obs: Observations) -> bundle.Problem:
    cams, views, corners, pixels, sigmas = [], [], [], [], []
    for v, row in enumerate(obs.corners):
        for c, found in enumerate(row):
            if found is None:
                continue
            ok = np.flatnonzero(np.isfinite(found.pixels).all(axis=1))
            cams.append(np.full(len(ok), c))
            views.append(np.full(len(ok), v))
            corners.append(ok)
            pixels.append(found.pixels[ok])
            sigmas.append(found.sigma_px[ok])
    return bundle.Problem(
        obs.pattern,
        obs.sizes,
        len(obs.corners),
        np.concatenate(cams),
        np.concatenate(views),
        np.concatenate(corners),
        np.concatenate(pixels),
        np.concatenate(sigmas),
    )


def _worst_per_image(
    problem: bundle.Problem, norm: FloatArray, above: NDArray[np.bool_]
) -> NDArray[np.bool_]:
    """Of the corners ``above`` the threshold, only the worst of each image.

    One bad corner pulls its view's pose and so its neighbours' errors: it goes first,
    and the others are judged again after the next solve. (Its caller also holds back
    corners under half the worst error: with few views a bad corner pulls the lens too,
    and the far corners of other views with it.)
    """
    out = np.zeros_like(above)
    rows = np.flatnonzero(above)
    order = rows[np.argsort(-norm[rows])]
    taken: set[tuple[int, int]] = set()
    for r in order:
        key = (int(problem.view[r]), int(problem.camera[r]))
        if key not in taken:
            taken.add(key)
            out[r] = True
    return out


def _solve_with_outliers(
    obs: Observations, problem: bundle.Problem, x: FloatArray
) -> tuple[FloatArray, FloatArray, bundle.Problem, list[Outlier]]:
    outliers: list[Outlier] = []
    for _ in range(ROUNDS):
        x, jac = bundle.adjust(x, problem)
        err = bundle.residuals(x, problem).reshape(-1, 2)
        norm = np.linalg.norm(err, axis=1)
        spread = np.median(norm) / np.sqrt(2 * np.log(2))  # per-axis sigma of a Rayleigh law
        above = (norm > OUTLIER_SIGMAS * spread) & (norm >= norm.max() / 2)
        bad = _worst_per_image(problem, norm, above)
        if not bad.any():
            break
        px = np.linalg.norm(bundle.project(x, problem) - problem.pixels, axis=1)
        outliers += [
            Outlier(obs.view_names[v], int(c), int(k), float(e))
            for v, c, k, e in zip(
                problem.view[bad], problem.camera[bad], problem.corner[bad], px[bad], strict=True
            )
        ]
        problem = problem.keep(~bad)
    else:  # the last round left corners out: solve once more without them
        x, jac = bundle.adjust(x, problem)
    return x, jac, problem, outliers


def _fit_residual_grids(
    obs: Observations,
    full: bundle.Problem,
    solved: tuple[FloatArray, FloatArray, bundle.Problem, list[Outlier]],
    option: GridOption,
) -> tuple[FloatArray, FloatArray, bundle.Problem, list[Outlier], dict[str, object]]:
    """Solve again with a residual grid per camera; keep it when the data supports it.

    The grid solve starts from ``solved`` (the rational model's solve of ``full``) but
    on every corner of ``full``: corners the rational model could not follow, left out
    as outliers, get a second chance. With ``"auto"`` the grids stay when the drop in the
    whitened squared residuals over the same corners, in units of the residuals'
    variance with the grids, exceeds twice the parameters they add (Akaike's
    criterion): corners that the rational model already fits to their noise leave the
    model as it was. A tuple of cells always keeps them.
    """
    x, jac, problem, rational_outliers = solved
    cells = DEFAULT_CELLS if option == "auto" else option
    assert isinstance(cells, tuple)
    xg, jac_g, grid_problem, outliers = _solve_with_outliers(
        obs, full.with_grid(cells), bundle.add_zero_grids(x, full, cells)
    )
    before = bundle.residuals(x, full.keep(_rows_kept(full, grid_problem)))
    after = bundle.residuals(xg, grid_problem)
    added = problem.cameras * (grid_problem.grid_controls - 6)  # mean and tilt held
    variance = float(after @ after) / max(len(after) - len(xg), 1)
    drop = (float(before @ before) - float(after @ after)) / variance
    kept = option != "auto" or drop > 2 * added
    note: dict[str, object] = {
        "cells": list(cells),
        "kept": kept,
        "chi2_drop": round(drop, 1),
        "parameters": added,
    }
    if not kept:
        return x, jac, problem, rational_outliers, note
    return xg, jac_g, grid_problem, outliers, note


def _rows_kept(problem: bundle.Problem, smaller: bundle.Problem) -> NDArray[np.bool_]:
    """Which rows of ``problem`` are still in ``smaller`` (a ``keep`` of it)."""
    key = (problem.view * problem.cameras + problem.camera) * 100_000 + problem.corner
    small = (smaller.view * smaller.cameras + smaller.camera) * 100_000 + smaller.corner
    return np.isin(key, small)


def _covariance(x: FloatArray, jac: FloatArray, problem: bundle.Problem) -> FloatArray:
    """The parameters' covariance under re-drawn corner noise, scaled by the residuals.

    The prior is not noise that a new set of views would re-draw, so the spread of the
    regularised solution is the sandwich ``A^-1 J^T J A^-1`` with ``A = J^T J + prior``
    (``(J^T J)^-1`` where the prior does not reach).
    """
    res = bundle.residuals(x, problem)
    dof = max(len(res) - len(x), 1)
    jtj, _ = bundle.normal_equations(jac, res)
    inverse = np.linalg.pinv(jtj + bundle.prior_matrix(problem))
    out: FloatArray = inverse @ jtj @ inverse * (res @ res / dof)
    return out


def _camera_result(
    x: FloatArray, problem: bundle.Problem, cov: FloatArray, c: int, grid_step_px: float
) -> CameraResult:
    lens = bundle.lens(x, problem, c)
    p = bundle.unpack(x, problem)
    rows = problem.camera == c
    d = bundle.project(x, problem)[rows] - problem.pixels[rows]
    block = cov[
        c * bundle.INTRINSICS : (c + 1) * bundle.INTRINSICS,
        c * bundle.INTRINSICS : (c + 1) * bundle.INTRINSICS,
    ]
    distance = float(np.median(np.linalg.norm(p.boards[:, 3:], axis=1)))
    pixels = pixel_grid(lens.width, lens.height, step_px=grid_step_px, margin=MARGIN)
    sigma = projection_uncertainty(lens, block, pixels, distance_mm=distance)
    shape = grid_shape(lens.width, lens.height, step_px=grid_step_px, margin=MARGIN)
    return CameraResult(
        lens,
        rotation_matrix(p.rig[c, :3]),
        p.rig[c, 3:].copy(),
        float(np.sqrt(np.mean(np.sum(d**2, axis=1)))),
        int(rows.sum()),
        float(np.sqrt(np.nanmean(sigma**2))),
        sigma.reshape(shape),
        np.column_stack([problem.pixels[rows], d]),
    )


def _view_results(
    obs: Observations, x: FloatArray, problem: bundle.Problem
) -> list[dict[str, object]]:
    d = np.linalg.norm(bundle.project(x, problem) - problem.pixels, axis=1)
    boards = bundle.unpack(x, problem).boards
    out = []
    for v, name in enumerate(obs.view_names):
        rows = problem.view == v
        per_cam = {
            str(c): float(np.sqrt(np.mean(d[rows & (problem.camera == c)] ** 2)))
            for c in range(problem.cameras)
            if np.any(rows & (problem.camera == c))
        }
        out.append(
            {
                "name": name,
                "rms_px": float(np.sqrt(np.mean(d[rows] ** 2))) if rows.any() else None,
                "cameras_rms_px": per_cam,
                "board_rvec": boards[v, :3].tolist(),
                "board_t_mm": boards[v, 3:].tolist(),
            }
        )
    return out


def calibrate(
    obs: Observations,
    *,
    cross_validate: bool = True,
    grid_step_px: float = 32.0,
    residual_grid: GridOption = "auto",
) -> Calibration:
    """Solve the calibration of ``obs``'s cameras; see the module's notes.

    ``grid_step_px`` is the spacing of the quality maps; ``residual_grid`` see
    `_fit_residual_grids` (``"off"``: the rational model alone).

    Raises
    ------
    CalibrationInputError
        When the views cannot give a calibration (the message says what to add).
    """
    seen = [v for v, row in enumerate(obs.corners) if any(f is not None for f in row)]
    used = obs.subset(seen)
    warnings = check_observations(used)
    full = make_problem(used)
    solved = _solve_with_outliers(used, full, bundle.pack(initial_guess(used)))
    x, jac, problem, outliers = solved
    grid_note: dict[str, object] = {"kept": False, "fitted": False}
    if residual_grid != "off":
        x, jac, problem, outliers, grid_note = _fit_residual_grids(
            used, full, solved, residual_grid
        )
    cov = _covariance(x, jac, problem)
    cameras = tuple(
        _camera_result(x, problem, cov, c, grid_step_px) for c in range(problem.cameras)
    )
    d = bundle.project(x, problem) - problem.pixels
    warp = bundle.unpack(x, problem).warp_mm
    result = Calibration(
        obs.pattern.spec,
        float(np.sqrt(np.mean(np.sum(d**2, axis=1)))),
        cameras,
        tuple(_view_results(used, x, problem)),
        (float(warp[0]), float(warp[1])),
        tuple(outliers),
        tuple(obs.missing()),
        tuple(warnings),
        grid_note,
    )
    if not cross_validate:
        return result
    cv = cross_validation(used, grid_step_px=grid_step_px, residual_grid=residual_grid)
    return replace(result, cross_validation=cv)


def cross_validation(
    obs: Observations, *, grid_step_px: float = 32.0, residual_grid: GridOption = "auto"
) -> dict[str, object]:
    """Two calibrations from alternate views; their projection difference per camera (px).

    ``expected_px`` is what two calibrations that differ only by their noise should show:
    the root sum of squares of their mean projection uncertainties.
    """
    halves = [obs.subset(list(range(k, len(obs.corners), 2))) for k in (0, 1)]
    try:
        fits = [
            calibrate(
                h, cross_validate=False, grid_step_px=grid_step_px, residual_grid=residual_grid
            )
            for h in halves
        ]
    except ValueError as e:
        return {"skipped": f"the halves of the views cannot be calibrated alone: {e}"}
    cams = []
    for c in range(obs.cameras):
        a, b = fits[0].cameras[c], fits[1].cameras[c]
        diff = projection_difference(a.lens, b.lens, step_px=grid_step_px, margin=MARGIN)
        cams.append(
            {
                "rms_px": float(np.sqrt(np.nanmean(diff**2))),
                "max_px": float(np.nanmax(diff)),
                "expected_px": float(np.hypot(a.uncertainty_px, b.uncertainty_px)),
            }
        )
    return {"cameras": cams}
