"""The simulator's lens blur (`elphel-sim up --lens-blur`): a Gaussian on the radiance."""

import numpy as np
import pytest

from elphel_camd.service import CameraService
from elphel_host.mfsr.gaussian_psf import GaussianPsf
from elphel_sim.board import SimCameraBoard
from elphel_sim.cli import build_parser
from elphel_sim.render import Intrinsics, LensBlur, blurred_strips, render_strips
from elphel_sim.scenarios import build
from elphel_sim.world import Plane, Pose, Scene, Texture, World

INTRINSICS = Intrinsics(focal_length_mm=4.5, pixel_pitch_um=2.2, width=640, height=480)
TIMES = np.zeros(1)
WINDOW = {"WOI_WIDTH": 96, "WOI_HEIGHT": 64, "WOI_LEFT": 1200, "WOI_TOP": 900, "EXPOS": 20000}


def _psf(sigma_px: float) -> GaussianPsf:
    return GaussianPsf.round(sigma_px)


@pytest.fixture(scope="module")
def world() -> World:
    texture = Texture.procedural(period_mm=200.0, seed=3, size=512)
    return World(Scene([Plane(texture, origin=(0.0, 0.0, 1000.0))]))


def strips(world: World, window, sigma: float, edge: float | None = None) -> np.ndarray:
    return blurred_strips(
        world,
        INTRINSICS,
        Pose.at((0.0, 0.0, 0.0)),
        window=window,
        times_s=TIMES,
        blur=LensBlur(_psf(sigma), None if edge is None else _psf(edge)),
    )


def test_no_blur_is_the_plain_render(world):
    window = (100, 80, 64, 48)
    plain = render_strips(world, INTRINSICS, Pose.at((0.0, 0.0, 0.0)), window=window, times_s=TIMES)
    assert np.array_equal(strips(world, window, 0.0), plain)


def test_a_window_is_blurred_as_the_whole_array_is(world):
    # the margin rendered around a window makes its blur the whole image's, cropped
    whole = strips(world, (0, 0, 640, 480), 0.7)
    part = strips(world, (200, 150, 96, 64), 0.7)
    assert part.shape == (1, 64, 96, 3)
    np.testing.assert_allclose(part, whole[:, 150:214, 200:296], rtol=0, atol=1e-12)


def test_the_blur_has_the_gaussian_transfer(world):
    sharp = strips(world, (0, 0, 640, 480), 0.0)[0, 100:-100, 100:-100, 1]
    soft = strips(world, (0, 0, 640, 480), 1.0)[0, 100:-100, 100:-100, 1]
    assert soft.mean() == pytest.approx(sharp.mean(), rel=1e-3)  # nothing lost
    # the power of the detail is what the transfer exp(-2 pi^2 sigma^2 f^2) leaves of it
    f = np.hypot(*np.meshgrid(np.fft.fftfreq(sharp.shape[1]), np.fft.fftfreq(sharp.shape[0])))
    band = (f > 0.05) & (f < 0.15)
    ratio = np.abs(np.fft.fft2(soft))[band] / np.abs(np.fft.fft2(sharp))[band]
    expected = np.exp(-2 * np.pi**2 * f[band] ** 2)
    assert np.median(ratio / expected) == pytest.approx(1.0, abs=0.05)


@pytest.mark.parametrize("forming", ["thread", "process"])
def test_the_board_forms_blurred_frames(forming):
    sharp, soft = (build("default", seed=2, lens_blur=LensBlur(_psf(b))) for b in (0.0, 1.5))
    assert [p.lens_blur.centre_px for p in soft.ports] == [1.5]
    assert sharp.ports[0].lens_blur == LensBlur()
    images = []
    for scenario in (sharp, soft):
        board = SimCameraBoard(scenario, seed=2, noise=False, forming=forming)
        try:
            camera = CameraService(board)
            camera.set_params(0, WINDOW)
            board.sim_advance(frames=4)
            frame, _ = camera.capture(0)
            images.append(frame.image[::2, ::2].astype(np.float64))  # one Bayer colour
        finally:
            board.close()
    sharp_img, soft_img = images
    assert sharp_img.shape == (32, 48) and sharp_img.std() > 50  # a textured wall
    assert soft_img.mean() == pytest.approx(sharp_img.mean(), rel=0.02)
    detail = [np.abs(np.diff(g, axis=1)).mean() for g in images]
    assert detail[1] < 0.6 * detail[0], detail


def test_a_blur_that_grows_towards_the_corners(world):
    # 0.3 px on the optical axis (the array's centre), 1.5 px at the corners: a patch
    # around (row 435, column 595) is 0.71 of the way out in squared radius, 1.15 px
    varying = strips(world, (0, 0, 640, 480), 0.3, 1.5)[0, ..., 1]
    uniform = {s: strips(world, (0, 0, 640, 480), s)[0, ..., 1] for s in (0.3, 0.7, 1.15, 1.5)}
    for patch, expected in ((np.s_[200:280, 280:360], 0.3), (np.s_[400:470, 560:630], 1.15)):
        err = {
            s: float(np.sqrt(np.mean((varying[patch] - u[patch]) ** 2))) for s, u in uniform.items()
        }
        assert min(err, key=err.get) == expected, err
    # a window of the array sees the same field-dependent blur
    part = strips(world, (500, 380, 96, 64), 0.3, 1.5)[0, ..., 1]
    np.testing.assert_allclose(part, varying[380:444, 500:596], rtol=0, atol=1e-9)


def test_cli_checks_the_blur():
    parse = build_parser().parse_args
    assert parse(["up", "--lens-blur", "0.35"]).lens_blur == LensBlur(_psf(0.35))
    assert parse(["up", "--lens-blur", "0.3:0.9"]).lens_blur == LensBlur(_psf(0.3), _psf(0.9))
    for bad in ("-1", "6", "nan", "x", "0.3:9", "1:2:3"):
        with pytest.raises(SystemExit):
            parse(["up", "--lens-blur", bad])
    with pytest.raises(ValueError, match="lens blur"):
        build("default", seed=0, lens_blur=LensBlur(_psf(9.0)))
