"""Camera model -> sensor image: sub-pixel exact radiance, Bayer mosaic, noise, quantisation.

Pixels integrate radiance over their area. Each plane's texture is band-limited, so the
area integral over a pixel's footprint is the texture convolved with the footprint's
box, sampled at the pixel centre: the box is applied once per (texture, footprint) as a
sinc product in the Fourier domain, and the filtered texture is then evaluated at every
pixel centre by cubic splines. Moving the camera by a distance therefore moves the image
by exactly the predicted fraction of a pixel. The footprint is taken at each plane's
visible centre, exact for planes facing the camera and a close approximation for slanted
ones.

Sensor coordinates: pixel (row r, column c) of the full array covers [c, c+1) x [r, r+1);
its centre is (c + 0.5, r + 0.5). The principal point defaults to the array centre.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from elphel_sim.world import FloatArray, Plane, Pose, Texture, World

Window = tuple[int, int, int, int]  # left, top, width, height in array pixels

BAYER_PATTERNS = ("RGGB", "GRBG", "GBRG", "BGGR")
_CHANNEL = {"R": 0, "G": 1, "B": 2}


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole camera intrinsics.

    Parameters
    ----------
    focal_length_mm
        Lens focal length.
    pixel_pitch_um
        Sensor pixel pitch.
    width, height
        Size of the sensor array in pixels (windows are given in this array's coordinates).
    cx, cy
        Principal point in array pixel coordinates; None = the array centre.
    """

    focal_length_mm: float
    pixel_pitch_um: float
    width: int
    height: int
    cx: float | None = None
    cy: float | None = None

    def __post_init__(self) -> None:
        if not self.focal_length_mm > 0:
            raise ValueError(f"focal_length_mm={self.focal_length_mm}; allowed: > 0")
        if not self.pixel_pitch_um > 0:
            raise ValueError(f"pixel_pitch_um={self.pixel_pitch_um}; allowed: > 0")
        if self.width < 1 or self.height < 1:
            raise ValueError(f"sensor size {self.width}x{self.height}; allowed: >= 1x1")

    @property
    def principal_point(self) -> tuple[float, float]:
        return (
            self.width / 2 if self.cx is None else self.cx,
            self.height / 2 if self.cy is None else self.cy,
        )

    @property
    def focal_length_px(self) -> float:
        return self.focal_length_mm * 1000.0 / self.pixel_pitch_um

    def shift_px(self, lateral_mm: float, depth_mm: float) -> float:
        """Image shift (pixels) of a point at ``depth_mm`` when the camera moves sideways."""
        return lateral_mm * self.focal_length_px / depth_mm


def _check_window(intrinsics: Intrinsics, window: Window | None) -> Window:
    if window is None:
        return (0, 0, intrinsics.width, intrinsics.height)
    left, top, width, height = window
    if width < 1 or height < 1:
        raise ValueError(f"window size {width}x{height}; allowed: >= 1x1")
    if left < 0 or top < 0 or left + width > intrinsics.width or top + height > intrinsics.height:
        raise ValueError(
            f"window {window} exceeds the {intrinsics.width}x{intrinsics.height} sensor array"
        )
    return (int(left), int(top), int(width), int(height))


# Filtered-texture spline coefficients, per texture and footprint. A burst from a stage
# only translates the camera, so every frame after the first reuses the same entry.
_COEFF_CACHE: weakref.WeakKeyDictionary[Texture, dict[tuple[float, ...], FloatArray]] = (
    weakref.WeakKeyDictionary()
)
_CACHE_PER_TEXTURE = 8


def _filtered_coefficients(texture: Texture, footprint: FloatArray) -> FloatArray:
    """Spline coefficients of the texture averaged over a pixel's footprint.

    ``footprint`` is the 2x2 Jacobian of grid coordinates (x, y) by pixel (x, y).
    """
    key = tuple(np.round(footprint.ravel(), 9))
    per_texture = _COEFF_CACHE.setdefault(texture, {})
    if key in per_texture:
        return per_texture[key]
    n = texture.size
    k = np.fft.fftfreq(n)
    ky, kx = np.meshgrid(k, k, indexing="ij")
    # Average over the parallelogram J @ [-1/2, 1/2]^2 = product of sincs of k . J[:, m].
    box = np.sinc(kx * footprint[0, 0] + ky * footprint[1, 0]) * np.sinc(
        kx * footprint[0, 1] + ky * footprint[1, 1]
    )
    filtered = np.fft.ifft2(np.fft.fft2(texture.data) * box).real
    coeffs: FloatArray = ndimage.spline_filter(filtered, order=3, mode="grid-wrap")
    if len(per_texture) >= _CACHE_PER_TEXTURE:
        per_texture.clear()
    per_texture[key] = coeffs
    return coeffs


@dataclass(frozen=True)
class _Rays:
    """World ray directions of pixel centres, d = a + bx * x + by * y (x, y in array px)."""

    origin: FloatArray
    a: FloatArray
    bx: FloatArray
    by: FloatArray
    xs: FloatArray
    ys: FloatArray


def _rays(intrinsics: Intrinsics, pose: Pose, window: Window) -> _Rays:
    left, top, width, height = window
    cx, cy = intrinsics.principal_point
    pitch_mm = intrinsics.pixel_pitch_um / 1000.0
    r = pose.rotation
    a = r[:, 2] * intrinsics.focal_length_mm - r[:, 0] * cx * pitch_mm - r[:, 1] * cy * pitch_mm
    return _Rays(
        origin=pose.position_mm,
        a=a,
        bx=r[:, 0] * pitch_mm,
        by=r[:, 1] * pitch_mm,
        xs=left + 0.5 + np.arange(width, dtype=np.float64),
        ys=top + 0.5 + np.arange(height, dtype=np.float64),
    )


def _plane_hit(
    rays: _Rays, plane: Plane, times_s: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Ray parameter and texture coordinates (mm) where each pixel's ray meets the plane.

    Returns arrays of shape (len(times_s), height, width): moving planes are met at each time.
    """
    u, v, n = plane.basis()
    velocity = np.asarray(plane.velocity_mm_s, dtype=np.float64)
    o = np.asarray(plane.origin, dtype=np.float64)[None, :] + times_s[:, None] * velocity[None, :]
    rel = rays.origin[None, :] - o  # camera centre relative to the plane origin, per time
    xs = rays.xs[None, None, :]
    ys = rays.ys[None, :, None]

    def dot(w: FloatArray) -> FloatArray:
        out: FloatArray = (w @ rays.a) + (w @ rays.bx) * xs + (w @ rays.by) * ys
        return out

    k = np.newaxis
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (-(rel @ n))[:, k, k] / dot(n)
    s_u = (rel @ u)[:, k, k] + t * dot(u)
    s_v = (rel @ v)[:, k, k] + t * dot(v)
    return t, s_u, s_v


def _footprint_mm(rays: _Rays, plane: Plane, time_s: float, x: float, y: float) -> FloatArray:
    """Jacobian d(s_u, s_v)/d(x, y) of plane coordinates by pixel coordinates at (x, y)."""
    probe = _Rays(
        rays.origin, rays.a, rays.bx, rays.by, np.array([x, x + 1.0, x]), np.array([y, y + 1.0])
    )
    _, su, sv = _plane_hit(probe, plane, np.array([time_s]))
    su, sv = su[0], sv[0]
    return np.array(
        [[su[0, 1] - su[0, 0], su[1, 0] - su[0, 0]], [sv[0, 1] - sv[0, 0], sv[1, 0] - sv[0, 0]]]
    )


def _render(
    world: World, intrinsics: Intrinsics, pose: Pose, win: Window, times_s: FloatArray
) -> FloatArray:
    rays = _rays(intrinsics, pose, win)
    height, width = win[3], win[2]
    out = np.full((len(times_s), height, width, 3), float(world.scene.background))
    nearest = np.full((len(times_s), height, width), np.inf)
    for plane in world.scene.planes:
        t, s_u, s_v = _plane_hit(rays, plane, times_s)
        visible = np.isfinite(t) & (t > 0) & (t < nearest)
        if plane.half_extent_mm is not None:
            hu, hv = plane.half_extent_mm
            visible &= (np.abs(s_u) <= hu) & (np.abs(s_v) <= hv)
        if not visible.any():
            continue
        k, rows, cols = np.nonzero(visible)
        x_mid = float(rays.xs[int(np.median(cols))])
        y_mid = float(rays.ys[int(np.median(rows))])
        tex = plane.texture
        grid_per_mm = tex.size / tex.period_mm
        t_mid = float(times_s[int(np.median(k))])
        footprint = _footprint_mm(rays, plane, t_mid, x_mid, y_mid) * grid_per_mm
        coeffs = _filtered_coefficients(tex, footprint)
        gx = np.mod(s_u[visible] * grid_per_mm, tex.size)
        gy = np.mod(s_v[visible] * grid_per_mm, tex.size)
        value = ndimage.map_coordinates(
            coeffs, [gy, gx], order=3, mode="grid-wrap", prefilter=False
        )
        out[visible] = value[:, None] * np.asarray(plane.albedo_rgb, dtype=np.float64)
        nearest[visible] = t[visible]
    return out


def render_radiance(
    world: World,
    intrinsics: Intrinsics,
    pose: Pose,
    *,
    window: Window | None = None,
    time_s: float | None = None,
) -> FloatArray:
    """Area-integrated scene radiance seen by each pixel of a window.

    Parameters
    ----------
    world
        The scene (and, through ``time_s``, where moving planes are).
    intrinsics, pose
        The camera.
    window
        ``(left, top, width, height)`` in array pixels; None = the whole array.
    time_s
        Scene time; None = ``world.time_s``.

    Returns
    -------
    numpy.ndarray
        float64, shape (height, width, 3): linear RGB radiance.
    """
    win = _check_window(intrinsics, window)
    t_now = world.time_s if time_s is None else time_s
    return _render(world, intrinsics, pose, win, np.array([t_now], dtype=np.float64))[0]


def render_strips(
    world: World, intrinsics: Intrinsics, pose: Pose, *, window: Window, times_s: FloatArray
) -> FloatArray:
    """The same window seen at several times (photo-finish strips), shape (K, H, W, 3)."""
    win = _check_window(intrinsics, window)
    times = np.asarray(times_s, dtype=np.float64).ravel()
    if times.size == 0:
        raise ValueError("times_s is empty; allowed: one or more times")
    return _render(world, intrinsics, pose, win, times)


def bayer_channels(
    pattern: str, shape: tuple[int, int], *, row0: int = 0, col0: int = 0
) -> NDArray[np.intp]:
    """Colour index (0 R, 1 G, 2 B) of every pixel of a window of a Bayer sensor.

    ``pattern`` names the colours of the array's 2x2 cell at even rows/columns
    (e.g. ``"GRBG"``); ``row0, col0`` are the window's origin in the array.
    """
    if pattern not in BAYER_PATTERNS:
        raise ValueError(f"bayer pattern {pattern!r}; allowed: {', '.join(BAYER_PATTERNS)}")
    cell = np.array(
        [[_CHANNEL[pattern[0]], _CHANNEL[pattern[1]]], [_CHANNEL[pattern[2]], _CHANNEL[pattern[3]]]]
    )
    r = (row0 + np.arange(shape[0])) % 2
    c = (col0 + np.arange(shape[1])) % 2
    out: NDArray[np.intp] = cell[r[:, None], c[None, :]]
    return out


def mosaic(rgb: FloatArray, pattern: str | None, *, row0: int = 0, col0: int = 0) -> FloatArray:
    """Sample an RGB radiance image through a Bayer filter (None: a mono sensor, mean of RGB)."""
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"rgb must have shape (H, W, 3), got {rgb.shape}")
    if pattern is None:
        mono: FloatArray = rgb.mean(axis=2)
        return mono
    ch = bayer_channels(pattern, rgb.shape[:2], row0=row0, col0=col0)
    out: FloatArray = np.take_along_axis(rgb, ch[..., None], axis=2)[..., 0]
    return out


@dataclass(frozen=True)
class SensorModel:
    """Photon-to-DN conversion of a sensor.

    Parameters
    ----------
    bits
        ADC depth; output is clipped to 0 .. 2**bits - 1.
    electrons_per_us
        Electrons collected per microsecond at radiance 1.0 (scene illumination x QE).
    full_well_e
        Saturation charge.
    dn_per_e
        Conversion gain at analog gain 1.0.
    read_noise_e
        Gaussian read noise (electrons RMS).
    black_level_dn
        Offset added to every pixel.
    """

    bits: int = 12
    electrons_per_us: float = 0.1
    full_well_e: float = 8000.0
    dn_per_e: float = 0.5
    read_noise_e: float = 3.0
    black_level_dn: float = 0.0


def expose(
    radiance: FloatArray,
    *,
    exposure_us: float,
    gain: float | FloatArray = 1.0,
    model: SensorModel = SensorModel(),
    rng: np.random.Generator | None = None,
) -> NDArray[np.uint16]:
    """Integrate radiance into quantised DN.

    Parameters
    ----------
    radiance
        Per-pixel radiance (after the colour filter), any shape.
    exposure_us
        Integration time.
    gain
        Analog gain, a scalar or an array broadcastable to ``radiance`` (per-colour gains).
    model
        The sensor's conversion.
    rng
        Source of shot and read noise; None renders the noise-free expectation.
    """
    if exposure_us < 0:
        raise ValueError(f"exposure_us={exposure_us}; allowed: >= 0")
    electrons = np.clip(radiance * (exposure_us * model.electrons_per_us), 0.0, model.full_well_e)
    if rng is not None:
        electrons = rng.poisson(electrons).astype(np.float64)
        electrons += rng.normal(0.0, model.read_noise_e, electrons.shape)
    dn = electrons * model.dn_per_e * gain + model.black_level_dn
    top = (1 << model.bits) - 1
    out: NDArray[np.uint16] = np.clip(np.rint(dn), 0, top).astype(np.uint16)
    return out
