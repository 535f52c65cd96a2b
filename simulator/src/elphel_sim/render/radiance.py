"""Scene radiance seen by each pixel of a pinhole camera, sub-pixel exact.

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

`render_strips` (how a simulated Bayer sensor's frames are formed) keeps its recent
results in a `RadianceCache`: a frame of a scene where nothing can have moved since an
earlier frame, seen from the same pose through the same window, reuses that frame's
radiance. `render_radiance` always renders.
"""

from __future__ import annotations

import weakref
from collections.abc import Hashable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from elphel_sim.render.radiance_cache import RADIANCE_CACHE, RadianceCache
from elphel_sim.world import FloatArray, Plane, Pose, Texture, World

Window = tuple[int, int, int, int]  # left, top, width, height in array pixels


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
# only translates the camera, so every frame after the first reuses the same entry (the
# footprint is quantised: see `_quantised`).
_COEFF_CACHE: weakref.WeakKeyDictionary[Texture, dict[tuple[float, ...], FloatArray]] = (
    weakref.WeakKeyDictionary()
)
_CACHE_PER_TEXTURE = 8
# The texture's half spectrum (rfft2), per texture: every footprint filters the same one.
_SPECTRUM_CACHE: weakref.WeakKeyDictionary[Texture, NDArray[np.complex128]] = (
    weakref.WeakKeyDictionary()
)
# Footprints are rounded to 2**-FOOTPRINT_BITS of their largest entry (a pixel 0.05-0.1 %
# wider or narrower for the box filter, far below a sensor's noise), so that the footprint
# a moving camera sees on a slanted plane, or the last digits of its finite differences,
# do not make every frame filter the texture anew (about 0.1 s per plane and frame).
FOOTPRINT_BITS = 10


def _quantised(footprint: FloatArray) -> FloatArray:
    """The footprint rounded to a power-of-two step 2**-FOOTPRINT_BITS of its magnitude."""
    scale = float(np.max(np.abs(footprint)))
    if not scale > 0:
        return np.asarray(footprint, dtype=np.float64)
    step = 2.0 ** (np.floor(np.log2(scale)) - FOOTPRINT_BITS)
    out: FloatArray = np.round(footprint / step) * step
    return out


def filtered_coefficients(texture: Texture, footprint: FloatArray) -> FloatArray:
    """Spline coefficients of the texture averaged over a pixel's footprint.

    ``footprint`` is the 2x2 Jacobian of grid coordinates (x, y) by pixel (x, y); it is
    quantised (`_quantised`) first, so the result depends on the key alone.
    """
    footprint = _quantised(footprint)
    key = tuple(footprint.ravel())
    per_texture = _COEFF_CACHE.setdefault(texture, {})
    if key in per_texture:
        return per_texture[key]
    n = texture.size
    spectrum = _SPECTRUM_CACHE.get(texture)
    if spectrum is None:
        spectrum = _SPECTRUM_CACHE[texture] = np.fft.rfft2(texture.data)
    # the box is even in k, so the real texture's half spectrum is all it needs
    ky, kx = np.meshgrid(np.fft.fftfreq(n), np.fft.rfftfreq(n), indexing="ij")
    # Average over the parallelogram J @ [-1/2, 1/2]^2 = product of sincs of k . J[:, m].
    box = np.sinc(kx * footprint[0, 0] + ky * footprint[1, 0]) * np.sinc(
        kx * footprint[0, 1] + ky * footprint[1, 1]
    )
    filtered = np.fft.irfft2(spectrum * box, s=texture.data.shape)
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
        coeffs = filtered_coefficients(tex, footprint)
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


def _array_key(a: FloatArray) -> tuple[str, tuple[int, ...], bytes]:
    a = np.asarray(a)
    return a.dtype.str, a.shape, a.tobytes()


def _strips_key(
    world: World, intrinsics: Intrinsics, pose: Pose, win: Window, times: FloatArray
) -> tuple[tuple[Plane, ...], Hashable]:
    """The scene's planes now and the key of everything `_render` reads (see RadianceCache)."""
    planes = tuple(world.scene.planes)
    static = not any(any(p.velocity_mm_s) for p in planes) and bool(np.isfinite(times).all())
    when = ("strips", times.size) if static else ("times", times.tobytes())
    key = (
        tuple(id(p) for p in planes),
        # Bytes, not values: -0.0 and 0.0 fill the image with different bits.
        np.float64(float(world.scene.background)).tobytes(),
        repr(intrinsics),
        _array_key(pose.position_mm),
        _array_key(pose.rotation),
        win,
        when,
    )
    return planes, key


def render_strips(
    world: World,
    intrinsics: Intrinsics,
    pose: Pose,
    *,
    window: Window,
    times_s: FloatArray,
    cache: RadianceCache | None = RADIANCE_CACHE,
) -> FloatArray:
    """The same window seen at several times (photo-finish strips).

    Parameters
    ----------
    world
        The scene; moving planes are where they are at each strip's time.
    intrinsics, pose
        The camera.
    window
        ``(left, top, width, height)`` in array pixels.
    times_s
        Scene time of each strip.
    cache
        Where recent results are kept and looked up (see `RadianceCache`: a frame of an
        unchanged, still scene from the same pose and window is rendered once); None
        renders every time. The result is the same bits either way.

    Returns
    -------
    numpy.ndarray
        float64, shape (strips, height, width, 3): linear RGB radiance, read-only.
    """
    win = _check_window(intrinsics, window)
    times = np.asarray(times_s, dtype=np.float64).ravel()
    if times.size == 0:
        raise ValueError("times_s is empty; allowed: one or more times")
    if cache is None:
        out = _render(world, intrinsics, pose, win, times)
        out.flags.writeable = False
        return out
    planes, key = _strips_key(world, intrinsics, pose, win, times)
    found = cache.get(key)
    if found is None:
        found = _render(world, intrinsics, pose, win, times)
        cache.put(key, planes, found)
    return found.view()
