"""PSFs recovered from a tile-processor quad's correction kernels (`--psf quad=DIR`)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from elphel_host.burst.io import write_burst
from elphel_host.cli import main
from elphel_host.mfsr.fuse import fuse_frames
from elphel_host.mfsr.gaussian_psf import GaussianPsf
from elphel_host.mfsr.metrics import psnr
from elphel_host.mfsr.psf_spec import GivenGrid, GivenKernel
from elphel_host.mfsr.psf_tp import QuadPsfs, SensorWindow, psf_from_kernel, quad_psf, quad_psfs
from elphel_host.mfsr.robust_config import RobustConfig
from elphel_host.mfsr.synth import make_burst, random_shifts
from elphel_sim import quad as simquad
from elphel_sim.render.sensor import mosaic

TARGET = 1.3  # sensor px: the Gaussian the kernels correct to
LEFT, RIGHT = 0.6, 1.0  # the lens's blur (sensor px) in the left and right halves
SIZE = 256  # LR frame side = the quad's image side


def _moments(psf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    yy, xx = np.mgrid[-7:8, -7:8].astype(np.float64)
    m = psf.sum()
    c = np.array([(psf * yy).sum() / m, (psf * xx).sum() / m])
    dy, dx = yy - c[0], xx - c[1]
    cov = np.array([[(psf * dy * dy).sum(), (psf * dy * dx).sum()], [0, (psf * dx * dx).sum()]])
    cov[1, 0] = cov[0, 1]
    return cov / m, c


def test_the_simulators_psfs_are_recovered_from_their_kernels() -> None:
    rig = simquad.QuadRig(width=384, height=288)
    ab = simquad.aberrations(rig, seed=5)  # elliptical, off-centre, 0.6-1.2 px
    fix = simquad.correction_kernels(ab, bayer=rig.bayer, target_sigma_px=TARGET)
    worst_sigma = worst_offset = 0.0
    for cam, iy, ix in np.ndindex(4, *fix.shape[2:4]):
        cov, centre = _moments(ab.psfs[cam, 1, iy, ix])  # green (RGB order)
        got = psf_from_kernel(fix[cam, 2, iy, ix], TARGET)  # green (R, B, G order)
        want = np.sqrt(np.linalg.eigvalsh(cov))[::-1]
        worst_sigma = max(worst_sigma, float(np.abs(np.array(got.sigmas) - want).max()))
        worst_offset = max(worst_offset, float(np.abs(np.array(got.offset) - centre).max()))
    # measured 0.0035 px and 0.0016 px
    assert worst_sigma < 0.02 and worst_offset < 0.02, (worst_sigma, worst_offset)


def _gauss15(sigma: float) -> np.ndarray:
    d = np.arange(-7, 8, dtype=np.float64)
    g = np.exp(-0.5 * (d / sigma) ** 2)
    return np.outer(g, g) / np.outer(g, g).sum()


def _quad(root: Path, *, target: float | None = TARGET) -> Path:
    """A mono quad whose cameras' lenses blur LEFT on the left half, RIGHT on the right."""
    rig = simquad.QuadRig(width=SIZE, height=SIZE, bayer=None)
    psfs = np.empty((4, 3, 1, 2, 15, 15))
    psfs[:, :, 0, 0], psfs[:, :, 0, 1] = _gauss15(LEFT), _gauss15(RIGHT)
    ab = simquad.Aberrations(psfs, step=SIZE // 2)
    fix = simquad.correction_kernels(ab, bayer=None, target_sigma_px=TARGET)
    images = np.zeros((4, SIZE, SIZE), np.uint16)
    return simquad.write_quad_dir(
        root, images, rig, kernels=(fix, ab.step), kernel_target_sigma_px=target
    )


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> tuple[np.ndarray, Path, Path]:
    """HR truth, a burst through the quad's camera 0 lens, the quad directory."""
    import skimage.data as sd

    root = tmp_path_factory.mktemp("psf_tp")
    hr = np.asarray(sd.astronaut().mean(axis=2), np.float32)[:512, :512] / 255.0
    # the lens on the HR grid (2 HR px per sensor px), half by half
    seen = hr.copy()
    seen[:, :256] = ndimage.gaussian_filter(hr, 2 * LEFT, mode="nearest")[:, :256]
    seen[:, 256:] = ndimage.gaussian_filter(hr, 2 * RIGHT, mode="nearest")[:, 256:]
    frames = make_burst(
        seen, random_shifts(16, seed=7, spread=2.0), scale=2, noise_sigma=0.005, seed=8
    )
    dn = [np.clip(np.rint(f * 4000), 0, 65535).astype(np.uint16) for f in frames]
    return hr, write_burst(root / "burst", dn), _quad(root / "quad")


def _fused(tmp_path: Path, burst: Path, capsys: pytest.CaptureFixture[str], *psf: str) -> tuple:
    out = tmp_path / f"sr{len(list(tmp_path.iterdir()))}.tif"
    rc = main(["mfsr", str(burst), "--scale", "2", "--out", str(out), "--float", "--json", *psf])
    assert rc == 0, capsys.readouterr().err
    import tifffile

    return tifffile.imread(out) / 4000.0, json.loads(capsys.readouterr().out)["psf"]


def test_a_calibrated_lens_is_used_by_mfsr(
    rig: tuple[np.ndarray, Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    hr, burst, quad = rig
    psfs = quad_psfs(quad)
    assert psfs.frame == (SIZE, SIZE) and psfs.step == SIZE // 2
    # measured 0.59 and 1.00: a 15x15 kernel sampled from a Gaussian is not quite one
    assert np.allclose([p.sigmas[0] for p in psfs.psfs[0]], [LEFT, RIGHT], atol=0.02)
    assert psfs.grid(2).shape[:2] == (1, 2)
    given, info = _fused(tmp_path, burst, capsys, "--psf", f"quad={quad}")
    assert info["model"] == "regions" and info["regions"] == [1, 2]
    assert all(c["source"] == "given" for c in info["cells"][0])
    plain, _ = _fused(tmp_path, burst, capsys, "--psf", "none")
    auto, _ = _fused(tmp_path, burst, capsys)
    scores = {
        name: psnr(hr, img, data_range=1.0, border=16)
        for name, img in (("given", given), ("none", plain), ("auto", auto))
    }
    # measured 30.12 dB given (29.80 with the fixed tau 0.04), 26.35 dB none, 26.77 dB estimated
    assert scores["given"] > scores["none"] + 2.0, scores
    assert scores["given"] > scores["auto"] + 2.0, scores


def test_quad_psf_errors(
    rig: tuple[np.ndarray, Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    hr, burst, quad = rig
    args = ["mfsr", str(burst), "--scale", "2", "--out", str(tmp_path / "x.tif")]
    cases = [
        (["--psf", f"quad={_quad(tmp_path / 'q', target=None)}"], "target_sigma_px is missing"),
        (["--psf", f"quad={quad},camera=4"], "camera=4; allowed: 0..3"),
        (["--psf", f"quad={quad},cam=1"], "allowed: quad=QUAD_DIR or quad=QUAD_DIR,camera=N"),
        (["--psf", f"quad={tmp_path}"], "no quad.json"),
    ]
    for extra, message in cases:
        assert main([*args, *extra]) != 0, extra
        assert message in capsys.readouterr().err, extra
    frames = make_burst(
        hr[:256, :256], random_shifts(8, seed=1), scale=2, noise_sigma=0.005, seed=8
    )
    small = write_burst(tmp_path / "small", [np.rint(f * 4000).astype(np.uint16) for f in frames])
    assert main(["mfsr", str(small), *args[2:], "--psf", f"quad={quad}"]) != 0
    assert "made for 256x256 frames" in capsys.readouterr().err


def _offset_psf(dy: float, dx: float) -> GaussianPsf:
    return GaussianPsf(cov=np.array([[0.5, 0.1], [0.1, 0.7]]), offset=(dy, dx))


def test_the_cells_under_a_window_of_the_sensor_and_its_flips() -> None:
    # 2x3 cells of 100 px on a 200x300 quad image; each cell's PSF off-centre its own way
    cells = [[_offset_psf(0.1 * iy, 0.1 * ix) for ix in range(3)] for iy in range(2)]
    quad = QuadPsfs(psfs=cells, step=100, window=SensorWindow(0, 0, 200, 300))
    whole = quad.grid(2)
    assert whole.shape[:2] == (2, 3)
    np.testing.assert_array_equal(quad.grid(2, SensorWindow(0, 0, 200, 300)), whole)
    inside = quad.grid(2, SensorWindow(left=210, top=120, height=60, width=80))
    assert inside.shape[:2] == (1, 1)
    np.testing.assert_allclose(inside[0, 0], whole[1, 2])  # the cell under the window
    right = quad.grid(2, SensorWindow(left=100, top=0, height=100, width=200))
    np.testing.assert_allclose(right[0], whole[0, 1:])
    # a frame mirrored left-right: its left region is the sensor's right, and mirrored
    flipped = quad.grid(2, SensorWindow(left=100, top=0, height=100, width=200, fliph=True))
    np.testing.assert_allclose(flipped[0, 0], whole[0, 2, :, ::-1])
    np.testing.assert_allclose(flipped[0, 1], whole[0, 1, :, ::-1])
    upside = quad.grid(2, SensorWindow(left=0, top=0, height=200, width=100, flipv=True))
    np.testing.assert_allclose(upside[:, 0], whole[::-1, 0, ::-1, :])
    # a quad whose own images are flipped the same way: nothing is mirrored
    both = QuadPsfs(psfs=cells, step=100, window=SensorWindow(0, 0, 200, 300, fliph=True))
    np.testing.assert_allclose(both.grid(2, SensorWindow(0, 0, 200, 300, fliph=True)), whole)
    with pytest.raises(ValueError, match=r"80x60 at \(250, 120\) on the sensor\) do not lie"):
        quad.grid(2, SensorWindow(left=250, top=120, height=60, width=80))


def _window_burst(root: Path, hr: np.ndarray, meta: dict[str, int], *, flip: bool) -> Path:
    """A burst of the sensor's right half (through the RIGHT lens), metadata ``meta``."""
    import tifffile

    seen = ndimage.gaussian_filter(hr, 2 * RIGHT, mode="nearest")[:, 256:]
    frames = make_burst(
        seen[:, ::-1] if flip else seen,
        random_shifts(16, seed=7, spread=2.0),
        scale=2,
        noise_sigma=0.005,
        seed=8,
    )
    dn = [np.clip(np.rint(f * 4000), 0, 65535).astype(np.uint16) for f in frames]
    burst = write_burst(root, dn)
    for path in sorted((burst / "frames").glob("*.tif")):
        image = tifffile.imread(path)
        tifffile.imwrite(path, image, description=json.dumps(meta), metadata=None)
    return burst


def test_a_burst_of_a_window_gets_the_psfs_under_it(
    rig: tuple[np.ndarray, Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    hr, _, quad = rig
    truth = hr[:, 256:]
    scores = {}
    for name, meta, flip in (
        ("right", {"WOI_LEFT": 128, "WOI_TOP": 0}, False),
        ("right mirrored", {"WOI_LEFT": 128, "WOI_TOP": 0, "FLIPH": 1}, True),
        ("claimed left", {"WOI_LEFT": 0, "WOI_TOP": 0}, False),
    ):
        burst = _window_burst(tmp_path / name, hr, meta, flip=flip)
        image, info = _fused(tmp_path, burst, capsys, "--psf", f"quad={quad}")
        assert info["source"] == "given", info
        seen = image[:, ::-1] if flip else image
        scores[name] = psnr(truth, seen, data_range=1.0, border=16)
    # measured 30.67 / 30.66 dB with the right half's lens (mirrored or not), 27.14 dB
    # with the left half's
    assert scores["right"] > scores["claimed left"] + 1.0, scores
    assert abs(scores["right mirrored"] - scores["right"]) < 0.3, scores
    outside = _window_burst(tmp_path / "outside", hr, {"WOI_LEFT": 200, "WOI_TOP": 0}, flip=False)
    args = ["mfsr", str(outside), "--scale", "2", "--out", str(tmp_path / "o.tif")]
    assert main([*args, "--psf", f"quad={quad}"]) != 0
    assert "do not lie within the quad's images (256x256 at (0, 0))" in capsys.readouterr().err


def test_a_bayer_quads_colours_each_get_their_own_psf(tmp_path: Path) -> None:
    import skimage.data as sd

    blur = {"R": 1.0, "G": 0.6, "B": 0.8}  # sensor px: a lens with axial colour
    rig = simquad.QuadRig(width=SIZE, height=SIZE, bayer="GRBG")
    psfs = np.empty((4, 3, 1, 1, 15, 15))
    for c, name in enumerate("RGB"):
        psfs[:, c, 0, 0] = _gauss15(blur[name])
    ab = simquad.Aberrations(psfs, step=SIZE)
    fix = simquad.correction_kernels(ab, bayer="GRBG", target_sigma_px=TARGET)
    images = np.zeros((4, SIZE, SIZE), np.uint16)
    quad = simquad.write_quad_dir(
        tmp_path / "quad", images, rig, kernels=(fix, ab.step), kernel_target_sigma_px=TARGET
    )
    found = quad_psfs(quad)
    assert found.colour_psfs is not None
    got = [round(p[0][0].sigmas[0], 2) for p in found.colour_psfs]
    assert np.allclose(got, [1.0, 0.6, 0.8], atol=0.03), got  # R, G, B
    assert found.psfs is found.colour_psfs[1]  # green serves where one PSF does

    hr = np.asarray(sd.astronaut(), np.float32)[:512, :512] / 255.0
    shifts = random_shifts(16, seed=7, spread=2.0)
    planes = [
        make_burst(
            ndimage.gaussian_filter(hr[..., c], 2 * blur[name], mode="nearest"),
            shifts,
            scale=2,
            noise_sigma=0.005,
            seed=8 + c,
        )
        for c, name in enumerate("RGB")
    ]
    mosaics = [mosaic(np.stack([p[k] for p in planes], axis=-1), "GRBG") for k in range(16)]
    psf = quad_psf(found, 2)
    assert isinstance(psf, GivenKernel) and psf.rgb is not None and psf.rgb.shape[0] == 3
    config = RobustConfig(psf=psf)
    own = fuse_frames(mosaics, scale=2, bayer="GRBG", config=config)
    green = fuse_frames(
        mosaics, scale=2, bayer="GRBG", config=replace(config, psf=replace(psf, rgb=None))
    )
    assert own.info["psf"]["per_colour"] is True
    score = {
        (name, c): psnr(hr[..., c], result.image[..., c], data_range=1.0, border=16)
        for name, result in (("own", own), ("green", green))
        for c in range(3)
    }
    # measured: red 28.57 against 26.33 dB, blue 29.00 against 27.73 dB with their own
    # PSFs; green 31.03 dB either way
    assert score["own", 0] > score["green", 0] + 1.0, score
    assert score["own", 2] > score["green", 2] + 0.5, score
    assert abs(score["own", 1] - score["green", 1]) < 0.05, score


def test_per_colour_psfs_are_checked() -> None:
    k = _gauss15(0.8)
    ok = GivenKernel(k, rgb=np.stack([k, k, k]))
    assert ok.rgb is not None and ok.rgb.shape == (3, 15, 15)
    grid = np.broadcast_to(k, (2, 2, 15, 15))
    assert GivenGrid(grid, rgb=np.stack([grid] * 3)).cell(1, 0).rgb.shape == (3, 15, 15)
    cases = [
        (lambda: GivenKernel(k, rgb=np.stack([k, k])), r"rgb: shape \(2, 15, 15\); allowed"),
        (lambda: GivenKernel(k, rgb=np.stack([k, k, -k])), r"rgb\[2\]: allowed: finite"),
        (
            lambda: GivenGrid(grid, rgb=np.stack([grid[:1]] * 3)),
            r"allowed: \(3, 2, 2, h, w\), each colour's grid of the same regions",
        ),
    ]
    for make, message in cases:
        with pytest.raises(ValueError, match=message):
            make()
