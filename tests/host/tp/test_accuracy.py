"""Disparity accuracy on quads with exactly known disparity (Fourier shifts, simulator renders)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from elphel_host.tp import io, processor
from elphel_host.tp.config import TpConfig
from elphel_host.tp.geometry import IDEAL_POSITIONS
from elphel_host.tp.images import QuadImages
from elphel_host.tp.tile_pass import measure
from elphel_sim import quad as simquad


def fourier_quad(
    size: int, disparity: float, *, bayer: str | None, noise: float = 0.0, seed: int = 0
) -> QuadImages:
    """Four views of one band-limited RGB texture moved exactly by -D * position_i."""
    rng = np.random.default_rng(seed)
    f = np.fft.fftfreq(size)
    fy, fx = f[:, None], f[None, :]
    fr = np.hypot(fx, fy)
    spec = (rng.normal(size=(3, size, size)) + 1j * rng.normal(size=(3, size, size))) / np.maximum(
        fr, 1 / size
    )
    spec *= fr <= 0.25
    spec[:, 0, 0] = 0
    views = []
    for px, py in IDEAL_POSITIONS:
        rgb = np.fft.ifft2(spec * np.exp(2j * np.pi * disparity * (fx * px + fy * py))).real
        rgb = 0.2 + 0.6 * (rgb - rgb.min()) / (rgb.max() - rgb.min())
        if bayer is None:
            img = rgb.mean(0)
        else:
            img = np.empty((size, size))
            img[0::2, 0::2] = rgb[1, 0::2, 0::2]
            img[0::2, 1::2] = rgb[0, 0::2, 1::2]
            img[1::2, 0::2] = rgb[2, 1::2, 0::2]
            img[1::2, 1::2] = rgb[1, 1::2, 1::2]
        views.append(img + noise * rng.normal(size=img.shape))
    return QuadImages(np.asarray(views, dtype=np.float32), bayer=bayer)


@pytest.mark.parametrize("bayer", [None, "GRBG"])
@pytest.mark.parametrize("disparity", [0.0, 0.37, 2.5, 5.2])
def test_fronto_parallel_exact_quads(bayer: str | None, disparity: float) -> None:
    q = fourier_quad(128, disparity, bayer=bayer)
    dsi = processor.disparity_map(q, config=TpConfig(threads=1))
    inner = (slice(2, -2), slice(2, -2))  # the image wraps around: skip the border tiles
    err = dsi["disparity"][inner] - disparity
    assert np.sqrt(np.mean(err**2)) <= 0.02
    for layer in ("disparity_hor", "disparity_vert"):
        assert np.sqrt(np.mean((dsi[layer][inner] - disparity) ** 2)) <= 0.03


def test_first_pass_alone_is_biased_and_refinement_fixes_it() -> None:
    q = fourier_quad(128, 2.5, bayer="GRBG")
    inner = (slice(2, -2), slice(2, -2))
    raw = measure(q, np.zeros(q.tiles), config=TpConfig(threads=1))
    assert np.mean(raw["residual"][inner]) < 2.5 - 0.2  # window pulls the peak towards 0
    dsi = processor.disparity_map(q, config=TpConfig(threads=1))
    assert abs(np.mean(dsi["disparity"][inner]) - 2.5) < 0.01


def test_noise_raises_error_and_lowers_strength() -> None:
    clean = processor.disparity_map(
        fourier_quad(128, 1.0, bayer="GRBG"), config=TpConfig(threads=1)
    )
    noisy = processor.disparity_map(
        fourier_quad(128, 1.0, bayer="GRBG", noise=0.02), config=TpConfig(threads=1)
    )
    inner = (slice(2, -2), slice(2, -2))
    assert np.std(noisy["disparity"][inner]) > np.std(clean["disparity"][inner])
    assert np.median(noisy["strength"][inner]) < np.median(clean["strength"][inner])


def test_threads_and_chunks_do_not_change_results() -> None:
    q = fourier_quad(96, 1.7, bayer="GRBG", noise=0.01)
    a = processor.disparity_map(q, config=TpConfig(threads=1, chunk_tiles=10_000))
    b = processor.disparity_map(q, config=TpConfig(threads=2, chunk_tiles=37))
    for k in a:
        assert np.allclose(a[k], b[k], atol=1e-5)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, simquad.TileTruth]:
    rig = simquad.QuadRig(width=640, height=480)
    return simquad.simulate_quad_dir(tmp_path_factory.mktemp("quad"), rig, seed=3)


def test_rendered_quad_accuracy_and_strength(rendered: tuple[Path, simquad.TileTruth]) -> None:
    root, truth = rendered
    qs = io.read_quad_dir(root)
    assert qs.full_scale_dn == 4095
    dsi = processor.disparity_map(qs.quad)
    err = dsi["disparity"] - truth.disparity
    for name in ("fronto_0", "fronto_0.37", "fronto_2.5", "fronto_5.2"):
        m = (truth.label == truth.names.index(name)) & truth.interior
        assert m.sum() >= 20, name
        assert np.sqrt(np.mean(err[m] ** 2)) <= 0.05, name
    m = (truth.label == truth.names.index("slanted")) & truth.interior
    assert np.sqrt(np.mean(err[m] ** 2)) <= 0.1
    flat = (truth.label == truth.names.index("flat")) & truth.interior
    textured = truth.textured & truth.interior
    # strength separates texture from no texture: 95 % of textured tiles above the flat median x2
    assert np.percentile(dsi["strength"][textured], 5) > 2 * np.median(dsi["strength"][flat])


def test_truth_matches_rig_formula() -> None:
    rig = simquad.QuadRig(width=256, height=192)
    scene = simquad.standard_scene(rig)
    truth = simquad.tile_truth(scene)
    m = truth.label == truth.names.index("fronto_2.5")
    assert np.allclose(truth.disparity[m], 2.5)
    assert abs(rig.disparity_px(rig.depth_mm(0.37)) - 0.37) < 1e-12


def test_scan_reaches_beyond_the_correlation_radius() -> None:
    q = fourier_quad(128, 9.0, bayer="GRBG")
    inner = (slice(3, -3), slice(3, -3))
    plain = processor.disparity_map(q, config=TpConfig(threads=1))
    scanned = processor.disparity_map(q, config=TpConfig(threads=1, scan=(0.0, 6.0)))
    assert np.sqrt(np.mean((plain["disparity"][inner] - 9.0) ** 2)) > 0.5  # reach is 7 px from 0
    assert np.sqrt(np.mean((scanned["disparity"][inner] - 9.0) ** 2)) <= 0.05


def test_no_refinement_reports_the_first_pass() -> None:
    q = fourier_quad(96, 0.8, bayer=None)
    dsi = processor.disparity_map(q, config=TpConfig(threads=1, refine_passes=0))
    assert np.all(dsi["target_disparity"] == 0.0)
    inner = (slice(2, -2), slice(2, -2))
    assert abs(np.median(dsi["disparity"][inner]) - 0.8) < 0.1
    assert np.isfinite(dsi["disparity_hor"]).all()


def test_a_coarse_first_pass_measures_the_same_tiles_and_keeps_the_accuracy(
    rendered: tuple[Path, simquad.TileTruth],
) -> None:
    q = fourier_quad(96, 1.3, bayer="GRBG", noise=0.01)
    config = TpConfig(threads=1)
    every = measure(q, np.zeros(q.tiles), config=config, full=False)
    coarse = measure(q, np.zeros(q.tiles), config=config, full=False, step=2)
    assert coarse["residual"].shape == ((q.tiles[0] + 1) // 2, (q.tiles[1] + 1) // 2)
    for k in ("residual", "strength", "levelled"):
        assert np.allclose(coarse[k], every[k][::2, ::2], atol=1e-5), k
    with pytest.raises(ValueError, match="first_pass_step=0"):
        TpConfig(first_pass_step=0)
    # the DSI of the rendered quad: within noise of a first pass over every tile
    root, truth = rendered
    quad = io.read_quad_dir(root).quad
    err = {
        step: processor.disparity_map(quad, config=TpConfig(first_pass_step=step))["disparity"]
        - truth.disparity
        for step in (1, 2)
    }
    for name in ("fronto_0.37", "fronto_5.2", "slanted"):
        m = (truth.label == truth.names.index(name)) & truth.interior
        rms = {step: np.sqrt(np.mean(e[m] ** 2)) for step, e in err.items()}
        assert rms[2] <= rms[1] + 0.005, (name, rms)
