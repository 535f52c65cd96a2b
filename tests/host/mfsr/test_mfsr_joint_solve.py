"""The batched solves: cross-validation folds and a Bayer burst's colour planes together."""

from __future__ import annotations

import numpy as np
import pytest

from elphel_host.mfsr.bayer import bayer_sites, colour_planes, frame_shifts, site_shifts
from elphel_host.mfsr.forward import ForwardModel, FourierSolver, solve_joint
from elphel_host.mfsr.ldl import solve_blocks
from elphel_host.mfsr.psf import NO_OPTICS, Optics
from elphel_host.mfsr.solve import (
    Geometry,
    Plane,
    SolveOptions,
    measure_passes,
    solve,
    solve_planes,
)
from elphel_host.mfsr.synth import make_bayer_burst, random_shifts


def test_batched_block_solve_matches_each_problem_alone():
    rng = np.random.default_rng(5)
    a, p = 9, 3
    grams = []
    for _ in range(p):
        c = rng.normal(size=(20, a)) + 1j * rng.normal(size=(20, a))
        grams.append((c.conj().T @ c).astype(np.complex64))
    d = rng.uniform(0.1, 1.0, (a, 6, 7)).astype(np.float32)
    prior = rng.uniform(0.01, 1.0, (a, p, 6, 7)).astype(np.float32)
    weight = rng.uniform(0.5, 2.0, p).astype(np.float32)
    b = (rng.normal(size=(a, p, 6, 7)) + 1j * rng.normal(size=(a, p, 6, 7))).astype(np.complex64)
    g = np.stack(grams, axis=-1)[..., None, None]
    batched = solve_blocks(d[:, None], g, prior, b, weight=weight, scale=1.5)
    for k in range(p):
        alone = solve_blocks(d, grams[k], prior[:, k], b[:, k], weight=weight[k], scale=1.5)
        # the same single-precision operations on the same numbers, broadcast
        assert np.array_equal(batched[:, k], alone)


def test_frame_shifts_undo_site_shifts():
    shifts = [(0.0, 0.0), (0.3, -0.7), (1.25, 0.5)]
    for sites in bayer_sites("GRBG").values():
        back = frame_shifts(site_shifts(shifts, sites), sites)
        assert np.allclose(back, shifts, atol=1e-12)
    with pytest.raises(ValueError, match="multiple of 2"):
        frame_shifts([(0.0, 0.0)] * 3, bayer_sites("GRBG")["G"])


@pytest.mark.parametrize("optics", [NO_OPTICS, Optics(0.6, None, 0.4)])
def test_colour_planes_solved_together_match_each_solved_alone(hr, optics):
    # a Bayer burst's three planes: one batched block solve per step against three solves;
    # each plane's own frames, shifts and noise (red and blue 16 frames, green 32)
    rgb = np.stack([hr, np.roll(hr, 5, axis=1), hr[::-1]], axis=-1)[:128, :128]
    shifts = random_shifts(16, seed=6, spread=2.0)
    frames = make_bayer_burst(rgb, shifts, scale=2, noise_sigma=0.01, seed=3)
    planes = colour_planes(frames, [tuple(s) for s in shifts], "GRBG")
    geometry = Geometry(4, 2)
    options = SolveOptions(passes=1, refine=True)
    noise = (0.011, 0.009, 0.012)
    todo = [Plane(f, s, optics, n) for (f, s), n in zip(planes, noise, strict=True)]
    together = solve_planes(todo, geometry, tau=0.05, options=options)
    for plane, (img, info) in zip(todo, together, strict=True):
        alone, alone_info = solve(
            plane.frames,
            plane.shifts,
            geometry,
            optics,
            tau=0.05,
            noise_sigma=plane.noise_sigma,
            options=options,
        )
        # the batch only broadcasts: every frequency's block sees the same single-precision
        # operations on the same numbers, and the frames are added in the same order
        assert np.array_equal(img, alone), np.abs(img - alone).max()
        assert info["noise_sigma"] == alone_info["noise_sigma"]
        assert info["shifts_refined"] == alone_info["shifts_refined"]


def test_measured_passes_are_the_solves_details(burst2):
    # the shifts and noise the passes measure do not need the solve after the last pass
    frames, shifts = burst2
    crop = [np.ascontiguousarray(f[:80, :96]) for f in frames]
    start = [tuple(s + 0.04) for s in shifts]
    options = SolveOptions(passes=2, refine=True, adapt_noise=True)
    args = (crop, start, Geometry(2), Optics(0.5, None, 0.3))
    _, info = solve(*args, tau=0.05, noise_sigma=0.02, options=options)
    measured = measure_passes(*args, tau=0.05, noise_sigma=0.02, options=options)
    assert measured == info
    assert measured["shifts_refined"] != [list(s) for s in start]  # the passes moved them
    assert measured["noise_sigma"] != 0.02


def test_solutions_and_images_in_given_memory_are_the_same(burst2):
    frames, shifts = burst2
    model = ForwardModel((64, 80), 2, 2)
    solver = FourierSolver(model, [tuple(s - np.rint(s)) for s in shifts], lam=0.01)
    solver.add_frames(range(len(frames)), [np.ascontiguousarray(f[:64, :80]) for f in frames])
    X = solve_joint([solver])
    again = solve_joint([solver], out=np.full_like(X, np.nan))
    assert np.array_equal(again, X)
    image = solver.to_image(X[0], shift_hr=(0.3, -0.2))
    memory = np.full(2 * image.size + 7, np.nan, np.float32)
    assert np.array_equal(solver.to_image(X[0], shift_hr=(0.3, -0.2), out=memory), image)
    with pytest.raises(ValueError, match="allowed: C-ordered"):
        solve_joint([solver], out=np.empty((1, 4, 64, 40), np.complex64))
    with pytest.raises(ValueError, match="allowed: C-ordered float32"):
        solver.to_image(X[0], out=memory[: image.size - 1])
