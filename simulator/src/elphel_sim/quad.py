"""Quad camera renders with exactly known disparity: the tile processor's test scenes.

A quad rig is four identical pinhole cameras (:mod:`elphel_sim.render`) on a square of
side ``baseline_mm``, all looking along +z with parallel axes, camera i at
``baseline * position_i`` (+x right, +y down, as quad.json positions). A point at depth
Z then appears in camera i at ``p - D * position_i`` with ``D = f B / (Z pitch)`` pixels,
p its position in a virtual camera at the centre. Because the renderer integrates
band-limited textures over each pixel's footprint, every camera's image is sub-pixel
exact, so the disparity of every plane is known without error;
:func:`elphel_sim.quad_truth.tile_truth` ray-casts the tile centres of the virtual centre
camera to give the true disparity per tile, and :mod:`elphel_sim.aberrations` adds a
space-variant blur when asked.

The standard scene (:func:`standard_scene`) has a far background (D = 0), fronto-parallel
rectangles at chosen disparities, a slanted rectangle (disparity varying linearly across
it), and a texture-less rectangle; their borders are depth edges.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from elphel_host.tp import io as quad_format
from elphel_sim.aberrations import Aberrations, aberrations, apply_aberrations, correction_kernels
from elphel_sim.quad_truth import TileTruth, tile_truth
from elphel_sim.render import Intrinsics, SensorModel, expose, mosaic, render_radiance
from elphel_sim.world import FloatArray, Plane, Pose, Scene, Texture, World

# The blur and the truth live in their own modules; these names stay importable from here.
__all__ = [
    "Aberrations",
    "QuadRig",
    "QuadScene",
    "Region",
    "TileTruth",
    "aberrations",
    "apply_aberrations",
    "correction_kernels",
    "fronto_rect",
    "render_quad",
    "simulate_quad_dir",
    "slanted_rect",
    "standard_scene",
    "tile_truth",
    "write_quad_dir",
]

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

    def fronto_box(
        self, disparity: float, box: tuple[float, float, float, float]
    ) -> tuple[float, FloatArray, tuple[float, float]]:
        """Depth, centre and half extents (mm) of a fronto-parallel rectangle at ``disparity``.

        ``box`` = (x0, y0, x1, y1) in fractions of the centre view.
        """
        z = self.depth_mm(disparity)
        x0, y0, x1, y1 = (
            box[0] * self.width,
            box[1] * self.height,
            box[2] * self.width,
            box[3] * self.height,
        )
        centre = self.point_mm(0.5 * (x0 + x1), 0.5 * (y0 + y1), z)
        s = z * self.pitch_mm / self.focal_length_mm
        return z, centre, (0.5 * (x1 - x0) * s, 0.5 * (y1 - y0) * s)


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
    #: The sensor window (WOI_LEFT, WOI_TOP, WOI_WIDTH, WOI_HEIGHT) whose pixels are the
    #: rig's, when that is not the whole default window.
    window: dict[str, int] | None = None

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
    z, centre, half = rig.fronto_box(disparity, box)
    tex = _scaled(_texture(seed, flat=not textured), rig, z)
    plane = Plane(
        tex,
        origin=tuple(centre),
        half_extent_mm=half,
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
    kernel_target_sigma_px: float | None = None,
) -> Path:
    """Write a quad directory: quad.json + cam0..3.tif (+ kernels.npy, step).

    ``kernel_target_sigma_px``: the Gaussian the kernels correct to (`correction_kernels`'
    ``target_sigma_px``), recorded beside them. The format is in docs/tile-processor.md,
    Files.
    """
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
        kernels=None
        if kernels is None
        else quad_format.KernelFile("kernels.npy", int(kernels[1]), kernel_target_sigma_px),
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
