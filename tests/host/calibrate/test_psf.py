"""Each camera's PSF over its field, from the checkerboard's edges, against the simulator's."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.special import erf

from elphel_host.calibrate.pattern import Checkerboard
from elphel_host.calibrate.psf import (
    PsfMeasurementError,
    fit_edge,
    measure_psfs,
    psf_field,
)
from elphel_host.cli import main as elphel_main
from elphel_host.mfsr.psf_spec import GivenGrid, load_kernel
from elphel_host.mfsr.psf_tp import psf_from_kernel
from elphel_host.tp.kernel_file import kernel_file
from elphel_sim.cli import main as sim_main

PATTERN = Checkerboard(9, 6, 25.0)


@pytest.fixture(scope="module")
def views(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("psf") / "views"
    argv = ["calib-views", str(root), "--cameras", "1", "--views", "6", "--width", "640"]
    assert sim_main([*argv, "--height", "480", "--seed", "21"]) == 0
    return root


def _true_sigma(truth: dict[str, Any], x: float, y: float) -> float:
    """The simulated lens's blur at a pixel (`elphel_sim.calib_rig.RigCamera.blur_px`)."""
    w, h, cx, cy = truth["width"], truth["height"], truth["cx"], truth["cy"]
    centre, edge = truth["blur_px"]
    r2_max = max(cx, w - 1 - cx) ** 2 + max(cy, h - 1 - cy) ** 2
    return float(centre + (edge - centre) * ((x - cx) ** 2 + (y - cy) ** 2) / r2_max)


def test_widths_per_region_match_the_simulators(views: Path) -> None:
    (field,), bayer = measure_psfs(views, PATTERN, cells=4)
    truth = json.loads((views / "truth.json").read_text())["cameras"][0]
    assert bayer == "GRBG" and field.sigma_px.shape == (3, 4) and field.step == 160
    assert field.used > 400
    for iy, ix in np.ndindex(*field.sigma_px.shape):
        x, y = min((ix + 0.5) * 160, 639), min((iy + 0.5) * 160, 479)
        assert field.sigma_px[iy, ix] == pytest.approx(_true_sigma(truth, x, y), abs=0.05)


def test_the_files_are_what_tp_and_mfsr_read(views: Path, tmp_path: Path) -> None:
    out = tmp_path / "psf"
    argv = ["calibrate", "psf", str(views), "--pattern", PATTERN.spec, "--out", str(out)]
    assert elphel_main([*argv, "--scale", "2", "--json"]) == 0
    doc = json.loads((out / "psf.json").read_text())
    sigma = np.asarray(doc["cameras"][0]["sigma_px"])
    entry = kernel_file(doc["kernels"], "psf.json")
    assert entry is not None and entry.step == 160 and entry.target_sigma_px == 1.3
    kernels = np.load(out / entry.file)
    assert kernels.shape == (1, 3, 3, 4, 15, 15)
    recovered = psf_from_kernel(kernels[0, 1, 1, 2], entry.target_sigma_px)
    assert recovered.sigmas[0] == pytest.approx(sigma[1, 2], abs=0.02)
    grid = load_kernel(out / "psf_cam0_x2.npy")
    assert isinstance(grid, GivenGrid) and grid.regions == (3, 4)
    centre = grid.grid[0, 0]
    ys = np.arange(centre.shape[0]) - centre.shape[0] // 2
    spread = np.sqrt((centre.sum(axis=1) * ys**2).sum())  # on the x2 grid
    assert spread == pytest.approx(2 * sigma[0, 0], rel=0.02)


def test_an_edge_width_is_fitted_from_its_samples() -> None:
    rng = np.random.default_rng(0)
    d = rng.uniform(-5, 5, 200)
    values = 100 + 80 * erf((d - 0.3) / (np.sqrt(2) * 1.2)) + rng.normal(0, 0.5, d.shape)
    assert fit_edge(d, values) == pytest.approx(1.2, abs=0.02)
    assert np.isnan(fit_edge(d[:5], values[:5]))


def test_too_few_edges_and_bad_options_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(PsfMeasurementError, match="3 edges measured; allowed: at least 30"):
        psf_field(np.ones((3, 3)), (640, 480), 160)
    argv = ["calibrate", "psf", str(tmp_path), "--pattern", PATTERN.spec, "--out", str(tmp_path)]
    for extra, said in ((["--cells", "9"], "1..8"), (["--target-sigma-px", "9"], "<= 5")):
        with pytest.raises(SystemExit) as e:
            elphel_main([*argv, *extra])
        assert e.value.code == 2 and said in capsys.readouterr().err
