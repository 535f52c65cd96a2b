"""Quad camera renders with exactly known disparity: the tile processor's test scenes.

A quad rig is four identical pinhole cameras (:mod:`elphel_sim.render`) on a square of
side ``baseline_mm``, all looking along +z with parallel axes, camera i at
``baseline * position_i`` (+x right, +y down, DESIGN 4.4). A point at depth Z then appears
in camera i at ``p - D * position_i`` with ``D = f B / (Z pitch)`` pixels, p its position
in a virtual camera at the centre. Because the renderer integrates band-limited textures
over each pixel's footprint, every camera's image is sub-pixel exact, so the disparity
of every plane is known without error; :func:`tile_truth` ray-casts the tile centres of
the virtual centre camera to give the true disparity per tile.

The standard scene (:func:`standard_scene`) has a far background (D = 0), fronto-parallel
rectangles at chosen disparities, a slanted rectangle (disparity varying linearly across
it), and a texture-less rectangle; their borders are depth edges.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from elphel_host.tp import io as quad_format
from elphel_sim.render import Intrinsics, SensorModel, expose, mosaic, render_radiance
from elphel_sim.world import FloatArray, Plane, Pose, Scene, Texture, World

IDEAL_POSITIONS = ((-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5))
FAR_DEPTH_MM = 1e12  # "infinity": disparity ~3e-7 px with the default rig
DEFAULT_SENSOR = SensorModel()


@dataclass(frozen=True)
class QuadRig:
    """Four identical cameras on a square (defaults: Elphel's 4.5 mm / 2.2 um / 150 mm)."""

    width: int = 2592
    height: int = 1936
    focal_length_mm: float = 4.5
    pixel_pitch_um: float = 2.2
    baseline_mm: float = 150.0
    bayer: str | None = "GRBG"
    positions: tuple[tuple[float, float], ...] = IDEAL_POSITIONS

    def __post_init__(self) -> None:
        if self.width % 8 or self.height % 8 or self.width <= 0 or self.height <= 0:
            raise ValueError(f"sensor {self.width}x{self.height}; allowed: positive multiples of 8")
        if not self.baseline_mm > 0:
            raise ValueError(f"baseline_mm={self.baseline_mm}; allowed: > 0")
        if len(self.positions) != 4:
            raise ValueError(f"positions must hold 4 (x, y) pairs, got {self.positions!r}")

    @property
    def intrinsics(self) -> Intrinsics:
        return Intrinsics(self.focal_length_mm, self.pixel_pitch_um, self.width, self.height)

    @property
    def pitch_mm(self) -> float:
        return self.pixel_pitch_um / 1000.0

    def depth_mm(self, disparity_px: float) -> float:
        """Depth of a fronto-parallel plane with this disparity (``Z = f B / (D pitch)``)."""
        if disparity_px <= 0:
            return FAR_DEPTH_MM
        return self.focal_length_mm * self.baseline_mm / (disparity_px * self.pitch_mm)

    def disparity_px(self, depth_mm: NDArray[np.floating] | float) -> NDArray[np.float64]:
        """Disparity of a point at a depth (``D = f B / (Z pitch)``)."""
        z = np.asarray(depth_mm, dtype=np.float64)
        out: NDArray[np.float64] = self.focal_length_mm * self.baseline_mm / (z * self.pitch_mm)
        return out

    def pose(self, camera: int) -> Pose:
        px, py = self.positions[camera]
        return Pose.at((self.baseline_mm * px, self.baseline_mm * py, 0.0))

    def point_mm(self, x_px: float, y_px: float, depth_mm: float) -> FloatArray:
        """3-D point seen by the virtual centre camera at continuous pixel (x, y)."""
        cx, cy = self.intrinsics.principal_point
        s = depth_mm * self.pitch_mm / self.focal_length_mm
        return np.array([(x_px - cx) * s, (y_px - cy) * s, depth_mm])


@dataclass(frozen=True)
class Region:
    """A named part of a scene and the plane that makes it."""

    name: str
    plane: Plane
    textured: bool = True


@dataclass
class QuadScene:
    """A scene for a quad rig with its named regions (nearest first when they overlap)."""

    rig: QuadRig
    regions: list[Region] = field(default_factory=list)

    @property
    def scene(self) -> Scene:
        return Scene(planes=[r.plane for r in self.regions])


def _texture(seed: int, *, flat: bool = False) -> Texture:
    # one texture sample is about half a pixel at the plane's depth: content reaches
    # ~0.25 cycles/pixel, band-limited so the renderer stays sub-pixel exact
    contrast = 0.0 if flat else 0.7
    return Texture.procedural(
        period_mm=1.0, seed=seed, size=512, band=0.25, contrast=contrast, mean=0.5
    )


def _scaled(texture: Texture, rig: QuadRig, depth_mm: float, sample_px: float = 0.5) -> Texture:
    period = texture.size * sample_px * depth_mm * rig.pitch_mm / rig.focal_length_mm
    return Texture(data=texture.data, period_mm=period)


def fronto_rect(
    rig: QuadRig,
    name: str,
    disparity: float,
    box: tuple[float, float, float, float],
    *,
    seed: int,
    textured: bool = True,
    albedo: tuple[float, float, float] = (0.9, 1.0, 0.8),
) -> Region:
    """A fronto-parallel rectangle on ``box`` = (x0, y0, x1, y1), fractions of the centre view."""
    z = rig.depth_mm(disparity)
    x0, y0, x1, y1 = (
        box[0] * rig.width,
        box[1] * rig.height,
        box[2] * rig.width,
        box[3] * rig.height,
    )
    centre = rig.point_mm(0.5 * (x0 + x1), 0.5 * (y0 + y1), z)
    s = z * rig.pitch_mm / rig.focal_length_mm
    tex = _scaled(_texture(seed, flat=not textured), rig, z)
    plane = Plane(
        tex,
        origin=tuple(centre),
        half_extent_mm=(0.5 * (x1 - x0) * s, 0.5 * (y1 - y0) * s),
        albedo_rgb=albedo,
    )
    return Region(name, plane, textured)


def slanted_rect(
    rig: QuadRig,
    name: str,
    disparities: tuple[float, float],
    box: tuple[float, float, float, float],
    *,
    seed: int,
) -> Region:
    """A rectangle whose disparity goes linearly from ``disparities[0]`` (left) to ``[1]``."""
    x0, y0, x1, y1 = (
        box[0] * rig.width,
        box[1] * rig.height,
        box[2] * rig.width,
        box[3] * rig.height,
    )
    ym = 0.5 * (y0 + y1)
    pl = rig.point_mm(x0, ym, rig.depth_mm(disparities[0]))
    pr = rig.point_mm(x1, ym, rig.depth_mm(disparities[1]))
    u = pr - pl
    half_u = 0.5 * float(np.linalg.norm(u))
    # the near end projects largest: size the height there so the trapezoid fits the box
    zmin = min(pl[2], pr[2])
    half_v = 0.5 * (y1 - y0) * zmin * rig.pitch_mm / rig.focal_length_mm
    # The plane is seen at a grazing angle: along u the texture is foreshortened. Scale it
    # so one texture sample spans >= half a pixel everywhere (content stays below Nyquist).
    f_px = rig.focal_length_mm / rig.pitch_mm
    unit = u / np.linalg.norm(u)
    px_per_mm = 0.0
    for t in np.linspace(0.0, 1.0, 9):
        p = pl + t * u
        q = p + unit  # 1 mm further along u
        du = f_px * abs(q[0] / q[2] - p[0] / p[2])
        dv = f_px / p[2]
        px_per_mm = max(px_per_mm, du, dv)
    base = _texture(seed)
    tex = Texture(data=base.data, period_mm=base.size * 0.5 / px_per_mm)
    plane = Plane(
        tex,
        origin=tuple(0.5 * (pl + pr)),
        u_axis=tuple(u),
        v_axis=(0.0, 1.0, 0.0),
        half_extent_mm=(half_u, half_v),
        albedo_rgb=(1.0, 0.9, 0.85),
    )
    return Region(name, plane)


def standard_scene(
    rig: QuadRig,
    *,
    disparities: tuple[float, ...] = (0.37, 2.5, 5.2),
    slant: tuple[float, float] = (2.0, 3.5),
    seed: int = 0,
) -> QuadScene:
    """Background at D = 0, fronto rectangles at ``disparities``, a slanted and a flat rectangle.

    Nearest regions are listed first; the background fills everything else.
    """
    regions: list[Region] = []
    n = len(disparities)
    # fronto rectangles side by side in the top half, then slanted and flat below
    for i, d in enumerate(disparities):
        x0 = 0.06 + i * (0.88 / n)
        regions.append(
            fronto_rect(
                rig, f"fronto_{d:g}", d, (x0, 0.06, x0 + 0.88 / n - 0.04, 0.48), seed=seed + 1 + i
            )
        )
    regions.append(slanted_rect(rig, "slanted", slant, (0.06, 0.56, 0.56, 0.94), seed=seed + 20))
    regions.append(
        fronto_rect(rig, "flat", 1.5, (0.64, 0.56, 0.94, 0.94), seed=seed + 30, textured=False)
    )
    regions.sort(key=lambda r: float(r.plane.origin[2]))
    background = fronto_rect(
        rig, "fronto_0", 0.0, (-2.0, -2.0, 3.0, 3.0), seed=seed + 40, albedo=(0.85, 0.95, 1.0)
    )
    regions.append(background)
    return QuadScene(rig, regions)


@dataclass(frozen=True)
class TileTruth:
    """True disparity of every tile centre of the virtual centre camera.

    Attributes
    ----------
    disparity
        ``(tiles_y, tiles_x)`` float64.
    label
        Index into ``names`` of the region seen at each tile centre (-1: nothing).
    names
        Region names.
    interior
        Tiles whose 16x16 footprint (plus the disparity shift) lies within one region in
        every camera: the ones whose disparity is defined without a depth edge.
    textured
        Whether each tile's region is textured.
    """

    disparity: NDArray[np.float64]
    label: NDArray[np.intp]
    names: tuple[str, ...]
    interior: NDArray[np.bool_]
    textured: NDArray[np.bool_]


def _cast(
    rig: QuadRig, scene: QuadScene, xs: NDArray[np.float64], ys: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.intp]]:
    """Depth and region label seen by the centre camera at continuous pixel coordinates."""
    cx, cy = rig.intrinsics.principal_point
    d = np.stack(
        [
            (xs - cx) * rig.pitch_mm,
            (ys - cy) * rig.pitch_mm,
            np.full(xs.shape, rig.focal_length_mm),
        ],
        -1,
    )
    best = np.full(xs.shape, np.inf)
    label = np.full(xs.shape, -1, dtype=np.intp)
    for i, region in enumerate(scene.regions):
        u, v, nrm = region.plane.basis()
        o = np.asarray(region.plane.origin, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (nrm @ o) / (d @ nrm)
        hit = t[..., None] * d
        ok = np.isfinite(t) & (t > 0) & (t < best)
        if region.plane.half_extent_mm is not None:
            hu, hv = region.plane.half_extent_mm
            ok &= (np.abs((hit - o) @ u) <= hu) & (np.abs((hit - o) @ v) <= hv)
        best = np.where(ok, t, best)
        label = np.where(ok, i, label)
    depth = best * rig.focal_length_mm
    return depth, label


def tile_truth(scene: QuadScene, *, margin_px: float = 12.0) -> TileTruth:
    """True per-tile disparity at tile centres (8tx+4, 8ty+4) of the virtual centre camera."""
    rig = scene.rig
    ty, tx = rig.height // 8, rig.width // 8
    yy, xx = np.meshgrid(8.0 * np.arange(ty) + 4.0, 8.0 * np.arange(tx) + 4.0, indexing="ij")
    depth, label = _cast(rig, scene, xx, yy)
    disparity = np.where(
        np.isfinite(depth), rig.disparity_px(np.where(np.isfinite(depth), depth, 1.0)), 0.0
    )
    # interior: same label on a ring of probes around the tile centre (tile half-size plus
    # the largest camera offset) in the centre view
    reach = margin_px + 0.5 * float(np.max(disparity)) * np.sqrt(2.0)
    interior = label >= 0
    for ang in np.linspace(0, 2 * np.pi, 16, endpoint=False):
        for r in (0.5 * reach, reach):
            _, lab = _cast(rig, scene, xx + r * np.cos(ang), yy + r * np.sin(ang))
            interior &= lab == label
    textured = np.array([r.textured for r in scene.regions])[np.maximum(label, 0)] & (label >= 0)
    return TileTruth(disparity, label, tuple(r.name for r in scene.regions), interior, textured)


@dataclass(frozen=True)
class Aberrations:
    """A space-variant blur per camera and colour: one 15x15 PSF per grid cell.

    ``psfs`` is ``(4, 3, ky, kx, 15, 15)`` in RGB order (row = 7 + dy); cell (kx, ky)
    covers pixels ``[kx*step, (kx+1)*step) x [ky*step, (ky+1)*step)``.
    """

    psfs: NDArray[np.float64]
    step: int


def aberrations(
    rig: QuadRig,
    *,
    seed: int,
    cells: tuple[int, int] = (2, 3),
    sigma_px: tuple[float, float] = (0.6, 1.2),
    max_offset_px: float = 0.3,
) -> Aberrations:
    """Random elliptical Gaussian PSFs, off-centre by up to ``max_offset_px``, per cell."""
    rng = np.random.default_rng(seed)
    ky, kx = cells
    step = int(np.ceil(max(rig.height / ky, rig.width / kx) / 8) * 8)
    ky, kx = -(-rig.height // step), -(-rig.width // step)
    yy, xx = np.mgrid[-7:8, -7:8].astype(np.float64)
    psfs = np.empty((4, 3, ky, kx, 15, 15))
    for idx in np.ndindex(4, 3, ky, kx):
        sx, sy = rng.uniform(*sigma_px, size=2)
        ang = rng.uniform(0, np.pi)
        ox, oy = rng.uniform(-max_offset_px, max_offset_px, size=2)
        c, s_ = np.cos(ang), np.sin(ang)
        u = c * (xx - ox) + s_ * (yy - oy)
        v = -s_ * (xx - ox) + c * (yy - oy)
        k = np.exp(-0.5 * ((u / sx) ** 2 + (v / sy) ** 2))
        psfs[idx] = k / k.sum()
    return Aberrations(psfs, step)


def apply_aberrations(rgb: FloatArray, psfs: NDArray[np.float64], step: int) -> FloatArray:
    """Blur an (H, W, 3) image with the PSF of the cell each pixel lies in."""
    h, w = rgb.shape[:2]
    out = np.empty_like(rgb)
    ky, kx = psfs.shape[1:3]
    for colour in range(3):
        for cy in range(ky):
            for cx in range(kx):
                y0, y1 = cy * step, min((cy + 1) * step, h)
                x0, x1 = cx * step, min((cx + 1) * step, w)
                if y0 >= y1 or x0 >= x1:
                    continue
                # convolve a margin-padded crop so the cell's pixels see their neighbours
                ya, yb, xa, xb = max(y0 - 8, 0), min(y1 + 8, h), max(x0 - 8, 0), min(x1 + 8, w)
                crop = ndimage.convolve(
                    rgb[ya:yb, xa:xb, colour], psfs[colour, cy, cx], mode="nearest"
                )
                out[y0:y1, x0:x1, colour] = crop[y0 - ya : y1 - ya, x0 - xa : x1 - xa]
    return out


def correction_kernels(
    ab: Aberrations, *, bayer: str | None, target_sigma_px: float = 1.3, eps: float = 1e-3
) -> NDArray[np.float32]:
    """Kernels that turn each camera's PSF into one common Gaussian (regularised inverse).

    Returns the tile processor's layout ``(4, colours, ky, kx, 15, 15)``: colours R, B, G
    for Bayer, one (the mean PSF's kernel) for mono.
    """
    n = 64
    f = np.fft.fftfreq(n)
    fr2 = f[:, None] ** 2 + f[None, :] ** 2
    target = np.exp(-2 * np.pi**2 * target_sigma_px**2 * fr2)
    psfs = ab.psfs
    if bayer is None:
        psfs = psfs.mean(axis=1, keepdims=True)
        order = [0]
    else:
        order = [0, 2, 1]  # RGB -> R, B, G
    out = np.empty((4, len(order), *psfs.shape[2:4], 15, 15), dtype=np.float32)
    for cam in range(4):
        for i, colour in enumerate(order):
            for cy, cx in np.ndindex(*psfs.shape[2:4]):
                big = np.zeros((n, n))
                big[:15, :15] = psfs[cam, colour, cy, cx]
                big = np.roll(big, (-7, -7), axis=(0, 1))  # centre at (0, 0)
                p = np.fft.fft2(big)
                kf = target * np.conj(p) / (np.abs(p) ** 2 + eps)
                k = np.roll(np.fft.ifft2(kf).real, (7, 7), axis=(0, 1))[:15, :15]
                out[cam, i, cy, cx] = k / k.sum()
    return out


def render_quad(
    scene: QuadScene,
    *,
    exposure_us: float = 70000.0,
    model: SensorModel = DEFAULT_SENSOR,
    seed: int | None = 0,
    blur: Aberrations | None = None,
) -> NDArray[np.uint16]:
    """The four raw images ``(4, H, W)`` uint16 (Bayer mosaic or mono), with noise when ``seed``.

    The default exposure puts radiance 1.0 near 90 % of the full well of the default
    12-bit sensor model; shot and read noise come from ``seed`` (None = noise-free).
    ``blur`` applies each camera's space-variant PSFs to the radiance before the mosaic.
    """
    rig = scene.rig
    world = World(scene.scene)
    rng = None if seed is None else np.random.default_rng(seed)
    out = []
    for cam in range(4):
        rgb = render_radiance(world, rig.intrinsics, rig.pose(cam))
        if blur is not None:
            rgb = apply_aberrations(rgb, blur.psfs[cam], blur.step)
        raw = mosaic(rgb, rig.bayer)
        out.append(expose(raw, exposure_us=exposure_us, model=model, rng=rng))
    return np.stack(out)


def write_quad_dir(
    path: str | Path,
    images: NDArray[np.uint16],
    rig: QuadRig,
    *,
    model: SensorModel = DEFAULT_SENSOR,
    extra: dict[str, object] | None = None,
    kernels: tuple[NDArray[np.float32], int] | None = None,
) -> Path:
    """Write a quad directory (DESIGN 4.4): quad.json + cam0..3.tif (+ kernels.npy, step)."""
    if images.shape[0] != 4:
        raise ValueError(f"images must have shape (4, H, W), got {images.shape}")
    manifest = quad_format.QuadManifest(
        cameras=quad_format.quad_cameras(rig.positions),
        bayer=rig.bayer,
        full_scale_dn=(1 << model.bits) - 1,
        optics={
            "focal_length_mm": rig.focal_length_mm,
            "pixel_pitch_um": rig.pixel_pitch_um,
            "baseline_mm": rig.baseline_mm,
        },
        kernels=None if kernels is None else quad_format.KernelFile("kernels.npy", int(kernels[1])),
        extra=dict(extra or {}),
    )
    return quad_format.write_quad_dir(
        path, manifest, list(images), kernels=None if kernels is None else kernels[0]
    )


def simulate_quad_dir(
    path: str | Path,
    rig: QuadRig,
    *,
    seed: int = 0,
    noise: bool = True,
    scene: QuadScene | None = None,
) -> tuple[Path, TileTruth]:
    """Render the standard scene (or ``scene``), write a quad directory, return the truth."""
    sc = standard_scene(rig, seed=seed) if scene is None else scene
    images = render_quad(sc, seed=seed if noise else None)
    root = write_quad_dir(path, images, rig)
    return root, tile_truth(sc)
