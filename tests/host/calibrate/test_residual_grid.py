"""The residual grid: the spline itself, and the solve that fits it where the lens needs it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from elphel_host.calibrate import bundle
from elphel_host.calibrate.camera_model import CameraModel
from elphel_host.calibrate.quality import projection_difference
from elphel_host.calibrate.residual_grid import ResidualGrid
from elphel_host.calibrate.solve import MARGIN, Calibration, calibrate
from elphel_sim.calib_rig import SmoothResidual, board_poses, make_rig

from .conftest import BOARD, TrueLens, observe

NOISE_PX = 0.01
RESIDUAL_PX = 0.2
RIG = make_rig(640, 480, seed=21, residual_px=RESIDUAL_PX)


def _pixels(width: int, height: int, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-0.5, width - 0.5, n), rng.uniform(-0.5, height - 0.5, n)])


def test_the_spline_weights_sum_to_one_and_a_constant_grid_is_that_constant() -> None:
    grid = ResidualGrid(640, 480, np.ones((7, 9, 2)) * [0.3, -0.1])
    pixels = _pixels(640, 480, 500, seed=1)
    _, weight = grid.basis(pixels)
    assert weight.sum(axis=1) == pytest.approx(1.0, abs=1e-12)
    assert grid.at(pixels) == pytest.approx(np.tile([0.3, -0.1], (500, 1)), abs=1e-12)


def test_least_squares_controls_follow_a_smooth_lens_residual() -> None:
    # The simulator's residual (cosines of up to 1.2 half-periods across the image) is
    # what the default 6 x 4 spans must hold to a few thousandths of a pixel.
    truth = SmoothResidual.random(640, 480, amplitude_px=0.3, seed=5)
    pixels = _pixels(640, 480, 4000, seed=2)
    grid = ResidualGrid.zeros(640, 480, (6, 4))
    index, weight = grid.basis(pixels)
    design = np.zeros((len(pixels), grid.controls_px.shape[0] * grid.controls_px.shape[1]))
    np.put_along_axis(design, index, weight, axis=1)
    controls, *_ = np.linalg.lstsq(design, truth.at(pixels), rcond=None)
    fitted = ResidualGrid(640, 480, controls.reshape(grid.controls_px.shape))
    check = _pixels(640, 480, 2000, seed=3)
    error = np.linalg.norm(fitted.at(check) - truth.at(check), axis=1)
    assert np.sqrt(np.mean(error**2)) < 0.005


def test_a_scaled_grid_moves_the_same_point_by_scale_times_as_much() -> None:
    rng = np.random.default_rng(4)
    grid = ResidualGrid(320, 240, rng.normal(0, 0.1, (7, 9, 2)))
    pixels = _pixels(320, 240, 100, seed=5)
    up = grid.scaled(3)
    assert up.at(3 * pixels + 1.0) == pytest.approx(3 * grid.at(pixels), abs=1e-12)


def test_a_lens_with_a_grid_round_trips_through_json_and_inverts() -> None:
    rng = np.random.default_rng(6)
    grid = ResidualGrid(640, 480, rng.normal(0, 0.2, (7, 9, 2)))
    lens = CameraModel(640, 480, 600.0, 601.0, 320.0, 240.0, (-0.2, 0.05, 0, 0, 0, 0, 0, 0), grid)
    back = CameraModel.from_json(json.loads(json.dumps(lens.to_json())))
    assert back.residual is not None
    assert back.residual.controls_px == pytest.approx(grid.controls_px, abs=1e-6)
    pixels = _pixels(640, 480, 300, seed=7)
    rays = back.rays(pixels)
    again = back.project(np.column_stack([rays, np.ones(len(rays))]))
    assert again == pytest.approx(pixels, abs=1e-6)


def test_a_grid_whose_cells_disagree_with_its_controls_is_refused() -> None:
    doc = ResidualGrid.zeros(640, 480, (6, 4)).to_json()
    doc["cells"] = [5, 4]
    with pytest.raises(ValueError, match="cells"):
        ResidualGrid.from_json(640, 480, doc)


def test_the_grid_prior_leaves_no_shift_or_tilt_and_is_positive_definite() -> None:
    prior = bundle.grid_prior((6, 4))
    assert np.linalg.eigvalsh(prior).min() > 0
    gx, gy = np.meshgrid(np.linspace(-1, 1, 9), np.linspace(-1, 1, 7))
    for field in (np.ones_like(gx), gx, gy):
        shift = np.stack([field, 0 * field], axis=-1).ravel() * 0.1
        assert shift @ prior @ shift > 1e4  # a 0.1 px shift or tilt costs far more than data


@pytest.fixture(scope="module")
def solved() -> dict[str, Calibration]:
    poses = board_poses(RIG, BOARD, 24, seed=50, warp_mm=(0.6, -0.4), min_cameras=2)
    obs = observe(RIG, poses, noise_px=NOISE_PX, seed=51)
    return {
        option: calibrate(obs, cross_validate=False, residual_grid=option)
        for option in ("off", "auto")
    }


def _difference_px(cal: Calibration, *, margin: float = MARGIN) -> list[float]:
    return [
        float(np.sqrt(np.mean(projection_difference(r.lens, TrueLens(c), margin=margin) ** 2)))
        for r, c in zip(cal.cameras, RIG.cameras, strict=True)
    ]


@pytest.mark.slow  # its fixture solves 24 views with and without grids
def test_a_lens_with_a_residual_gets_a_grid_that_brings_it_within_a_few_hundredths(
    solved: dict[str, Calibration],
) -> None:
    off, auto = solved["off"], solved["auto"]
    assert auto.residual_grid["kept"] is True
    assert all(c.lens.residual is not None for c in auto.cameras)
    without, with_grid = _difference_px(off), _difference_px(auto)
    assert min(without) > 0.1  # the rational model alone cannot follow this lens
    assert max(with_grid) < 0.5 * min(without)
    # Where the boards fell (the middle 60 % of each side) the grid follows the lens to
    # the corners' noise; towards the edges it extrapolates, as the rational model does.
    assert max(_difference_px(auto, margin=0.2)) < 0.02
    # What is left in the corners is their noise: per axis within 15 % of it.
    assert auto.rms_px / np.sqrt(2) == pytest.approx(NOISE_PX, rel=0.15)


def test_a_lens_without_a_residual_keeps_the_rational_model_alone() -> None:
    rig = make_rig(640, 480, seed=21)
    poses = board_poses(rig, BOARD, 16, seed=22, min_cameras=2)
    cal = calibrate(observe(rig, poses, noise_px=NOISE_PX, seed=24), cross_validate=False)
    assert cal.residual_grid["kept"] is False
    assert all(c.lens.residual is None for c in cal.cameras)


def test_a_forced_grid_is_kept_and_written_with_its_loss(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from elphel_host.calibrate.export import write_exports
    from elphel_host.calibrate.result import write_calibration

    poses = board_poses(RIG, BOARD, 12, seed=30, min_cameras=2)
    obs = observe(RIG, poses, noise_px=NOISE_PX, seed=31)
    cal = calibrate(obs, cross_validate=False, residual_grid=(4, 3))
    assert cal.residual_grid["kept"] is True and cal.residual_grid["cells"] == [4, 3]
    exports = write_exports(cal, tmp_path)
    path = write_calibration(cal, tmp_path, extra={"exports": exports})
    doc = json.loads(path.read_text())
    lens = CameraModel.from_json(doc["cameras"][1])
    assert lens.residual is not None and lens.residual.cells == (4, 3)
    losses = exports["mrcal"]["loss_px"]  # type: ignore[index]
    assert [round(x["rms_px"], 6) for x in losses] == [
        round(c.lens.residual.size_px()[0], 6)
        for c in cal.cameras  # type: ignore[union-attr]
    ]
    assert min(x["max_px"] for x in losses) > 0.05
