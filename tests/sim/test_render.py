"""The renderer is sub-pixel exact: camera motion moves the image by the predicted amount."""

import cv2
import numpy as np
import pytest

from elphel_sim.render import (
    Intrinsics,
    SensorModel,
    bayer_channels,
    expose,
    mosaic,
    render_radiance,
)
from elphel_sim.world import Plane, Pose, Scene, Texture, World

INTRINSICS = Intrinsics(focal_length_mm=4.5, pixel_pitch_um=2.2, width=2592, height=1944)
DEPTH_MM = 1000.0
WINDOW = (1100, 850, 256, 256)


@pytest.fixture(scope="module")
def world() -> World:
    texture = Texture.procedural(period_mm=400.0, seed=7, size=1024)
    return World(Scene([Plane(texture, origin=(0.0, 0.0, DEPTH_MM))]))


def green(world: World, x_mm: float, y_mm: float = 0.0, window=WINDOW) -> np.ndarray:
    rgb = render_radiance(world, INTRINSICS, Pose.at((x_mm, y_mm, 0.0)), window=window)
    return rgb[..., 1].astype(np.float32)


def ecc_shift(reference: np.ndarray, moved: np.ndarray) -> tuple[float, float]:
    """Translation (x, y) that maps `reference` onto `moved`, by OpenCV's ECC."""
    warp = np.eye(2, 3, dtype=np.float32)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 500, 1e-10)
    _, warp = cv2.findTransformECC(
        reference, moved, warp, cv2.MOTION_TRANSLATION, criteria, None, 5
    )
    # ECC's warp maps reference coordinates to where the same content is in `moved`.
    return float(warp[0, 2]), float(warp[1, 2])


@pytest.mark.parametrize("shift_px", [0.25, 0.5])
@pytest.mark.parametrize("axis", ["x", "y"])
def test_camera_motion_shifts_image_by_predicted_subpixel_amount(world, shift_px, axis):
    # Moving the camera by +d moves the image of a plane at depth Z by -d * f / Z.
    move_mm = shift_px * DEPTH_MM / INTRINSICS.focal_length_px
    assert INTRINSICS.shift_px(move_mm, DEPTH_MM) == pytest.approx(shift_px)
    reference = green(world, 0.0)
    moved = green(world, move_mm, 0.0) if axis == "x" else green(world, 0.0, move_mm)
    sx, sy = ecc_shift(reference, moved)
    expected = (-shift_px, 0.0) if axis == "x" else (0.0, -shift_px)
    assert sx == pytest.approx(expected[0], abs=0.02)
    assert sy == pytest.approx(expected[1], abs=0.02)


def test_whole_pixel_motion_equals_window_offset_exactly(world):
    move_mm = 3.0 * DEPTH_MM / INTRINSICS.focal_length_px
    left, top, w, h = WINDOW
    moved = green(world, move_mm, window=(left - 3, top, w, h))
    assert np.abs(moved - green(world, 0.0)).max() < 1e-5


def test_pixels_integrate_area_not_point_samples():
    # A pattern at exactly one cycle per pixel integrates to its mean over every pixel.
    n = 512
    x = np.arange(n) / n
    period_mm = 400.0
    texture = Texture(0.5 + 0.4 * np.cos(2 * np.pi * 64 * x)[None, :].repeat(n, 0), period_mm)
    world = World(Scene([Plane(texture, origin=(0.0, 0.0, DEPTH_MM))]))
    # Choose the focal length so that one texture cycle (period/64 mm) spans one pixel.
    pixel_on_plane_mm = period_mm / 64
    f_mm = 2.2e-3 * DEPTH_MM / pixel_on_plane_mm
    intr = Intrinsics(focal_length_mm=f_mm, pixel_pitch_um=2.2, width=64, height=64)
    image = render_radiance(world, intr, Pose.at((0.123, 0.0, 0.0)))[..., 0]
    assert np.abs(image - 0.5).max() < 1e-3


def test_nearer_plane_occludes_farther(world):
    far = world.scene.planes[0]
    near_texture = Texture(np.full((8, 8), 0.25), period_mm=10.0)
    near = Plane(near_texture, origin=(0.0, 0.0, 500.0), half_extent_mm=(50.0, 50.0))
    scene = World(Scene([far, near]))
    image = render_radiance(scene, INTRINSICS, Pose.at((0, 0, 0)))[..., 1]
    cx, cy = int(INTRINSICS.width / 2), int(INTRINSICS.height / 2)
    assert image[cy, cx] == pytest.approx(0.25, abs=1e-6)
    assert abs(image[10, 10] - 0.25) > 1e-3


def test_bayer_grbg_cell_and_window_phase():
    ch = bayer_channels("GRBG", (2, 2))
    assert ch.tolist() == [[1, 0], [2, 1]]
    # A window starting on an odd column starts on the cell's second column.
    assert bayer_channels("GRBG", (2, 2), col0=1).tolist() == [[0, 1], [1, 2]]
    rgb = np.zeros((2, 2, 3))
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 1.0, 2.0, 3.0
    assert mosaic(rgb, "GRBG").tolist() == [[2.0, 1.0], [3.0, 2.0]]
    with pytest.raises(ValueError, match="allowed"):
        bayer_channels("XYZW", (2, 2))


def test_exposure_and_gain_scale_signal_and_noise_has_a_seed():
    radiance = np.full((64, 64), 0.5)
    model = SensorModel(bits=12, electrons_per_us=0.1, dn_per_e=0.5)
    one = expose(radiance, exposure_us=10_000, model=model)
    two = expose(radiance, exposure_us=20_000, model=model)
    gained = expose(radiance, exposure_us=10_000, gain=2.0, model=model)
    assert one.dtype == np.uint16
    assert two.mean() == pytest.approx(2 * one.mean(), rel=1e-3)
    assert gained.mean() == pytest.approx(2 * one.mean(), rel=1e-3)
    a = expose(radiance, exposure_us=10_000, model=model, rng=np.random.default_rng(3))
    b = expose(radiance, exposure_us=10_000, model=model, rng=np.random.default_rng(3))
    assert np.array_equal(a, b)
    # Shot noise: variance in electrons equals the mean (plus read noise).
    electrons = a.astype(float) / model.dn_per_e
    assert electrons.var() == pytest.approx(500 + model.read_noise_e**2, rel=0.1)
    saturated = expose(radiance, exposure_us=1e7, model=model)
    assert saturated.max() <= 4095


def test_window_outside_the_array_is_rejected(world):
    with pytest.raises(ValueError, match="exceeds"):
        render_radiance(world, INTRINSICS, Pose.at((0, 0, 0)), window=(2500, 0, 200, 10))


@pytest.mark.parametrize("mean_e", [2.0, 10.0, 29.0, 30.0, 200.0])
def test_shot_and_read_noise_has_the_sensors_mean_and_variance_at_low_and_high_counts(mean_e):
    # Exact Poisson below POISSON_EXACT_BELOW_E electrons, one normal draw at and above it:
    # either way the mean is the signal and the variance the signal plus read noise squared.
    black = 100.0  # keeps negative read noise from being clipped at zero
    model = SensorModel(
        bits=16, electrons_per_us=0.01, dn_per_e=1.0, read_noise_e=3.0, black_level_dn=black
    )
    radiance = np.full((256, 256), mean_e / (1000 * model.electrons_per_us))
    dn = expose(radiance, exposure_us=1000, model=model, rng=np.random.default_rng(5))
    electrons = dn.astype(float) - black
    assert electrons.mean() == pytest.approx(mean_e, abs=0.05)
    assert electrons.var() == pytest.approx(mean_e + 9.0 + 1 / 12, rel=0.03)
