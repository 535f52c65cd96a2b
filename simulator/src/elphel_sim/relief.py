"""A scene with relief for the quad camera on the stage, and its ground truth.

`relief_scene` builds what the depth work is measured on: a textured back wall, a
staircase of three fronto-parallel steps (depth edges between them), a slanted plane,
and a vertical cylinder (a smooth curved surface, made of narrow planar facets whose
chords stay within millimetres of the true circle), all textured with detail up to one
cycle per pixel - above the sensor's Nyquist frequency, so aliasing carries what
super-resolution recovers. Depths are given as disparities of the default rig
(``D = f B / (Z p)``), 1 to 5.4 px.

The truth: `depth_map` ray-casts one camera (depth Z along the optical axis, per pixel),
`surface_cloud` the virtual centre camera on a dense grid (the true surface as the
cameras see it), `write_truth` writes both (``reference.ply``, ``depth_cam0.tif`` ..
``depth_cam3.tif``) and `render_quad_at` renders the quad after the carriage moved.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tifffile
from numpy.typing import NDArray

from elphel_host.cloud.ply import PointCloud, write_ply
from elphel_host.fileio import replacing
from elphel_sim.quad import DEFAULT_SENSOR, QuadRig, QuadScene, Region
from elphel_sim.quad_truth import nearest_hits
from elphel_sim.render import Intrinsics, SensorModel, expose, mosaic, render_radiance
from elphel_sim.world import FloatArray, Plane, Pose, Texture, World

#: One texture sample spans at most this many pixels: with ``band`` 0.5 the content then
#: reaches 1 cycle/px, twice the sensor's Nyquist frequency.
SAMPLE_PX = 0.25
TEXTURE_BAND = 0.5
TEXTURE_SIZE = 1024
CYLINDER_FACETS = 30


@dataclass(frozen=True)
class ReliefSpec:
    """Disparities (px of the default rig) of the relief scene's parts."""

    wall: float = 1.0
    steps: tuple[float, float, float] = (4.2, 4.8, 5.4)
    slant: tuple[float, float] = (1.5, 3.5)
    cylinder_front: float = 3.5
    cylinder_radius_mm: float = 20000.0


def _px_per_mm(
    rig: QuadRig, origin: FloatArray, u: FloatArray, v: FloatArray, half: tuple[float, float]
) -> float:
    """Largest image-plane pixels per mm of the plane (along u or v) over its extent."""
    f_px = rig.focal_length_mm / rig.pitch_mm
    best = 0.0
    for a in np.linspace(-1.0, 1.0, 5):
        for b in np.linspace(-1.0, 1.0, 5):
            p = origin + a * half[0] * u + b * half[1] * v
            for axis in (u, v):
                q = p + axis
                d = f_px * np.hypot(q[0] / q[2] - p[0] / p[2], q[1] / q[2] - p[1] / p[2])
                best = max(best, float(d))
    return best


def _plane(
    rig: QuadRig,
    name: str,
    origin: FloatArray,
    u: FloatArray,
    v: FloatArray,
    half: tuple[float, float],
    *,
    seed: int,
    albedo: tuple[float, float, float],
) -> Region:
    base = Texture.procedural(
        period_mm=1.0, seed=seed, size=TEXTURE_SIZE, band=TEXTURE_BAND, contrast=0.7, mean=0.5
    )
    period = base.size * SAMPLE_PX / _px_per_mm(rig, origin, u, v, half)
    plane = Plane(
        Texture(base.data, period),
        origin=tuple(origin),
        u_axis=tuple(u),
        v_axis=tuple(v),
        half_extent_mm=half,
        albedo_rgb=albedo,
    )
    return Region(name, plane)


def _fronto(
    rig: QuadRig,
    name: str,
    disparity: float,
    box: tuple[float, float, float, float],
    *,
    seed: int,
    albedo: tuple[float, float, float],
) -> Region:
    _, centre, half = rig.fronto_box(disparity, box)
    ex, ey = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    return _plane(rig, name, centre, ex, ey, half, seed=seed, albedo=albedo)


def _slanted(rig: QuadRig, slant: tuple[float, float], *, seed: int) -> Region:
    """The slanted plane: disparity linear from the left to the right edge of its box."""
    x0, x1, y0, y1 = 0.05 * rig.width, 0.50 * rig.width, 0.55 * rig.height, 0.94 * rig.height
    pl = rig.point_mm(x0, 0.5 * (y0 + y1), rig.depth_mm(slant[0]))
    pr = rig.point_mm(x1, 0.5 * (y0 + y1), rig.depth_mm(slant[1]))
    u = pr - pl
    zmin = min(pl[2], pr[2])
    half_v = 0.5 * (y1 - y0) * zmin * rig.pitch_mm / rig.focal_length_mm
    return _plane(
        rig,
        "slanted",
        0.5 * (pl + pr),
        u / np.linalg.norm(u),
        np.array([0, 1.0, 0]),
        (0.5 * float(np.linalg.norm(u)), half_v),
        seed=seed,
        albedo=(1.0, 0.9, 0.85),
    )


def _cylinder(rig: QuadRig, spec: ReliefSpec, *, seed: int) -> list[Region]:
    """The cylinder's facets: vertical axis, front at ``spec.cylinder_front``, at x = 0.74."""
    r = spec.cylinder_radius_mm
    z_front = rig.depth_mm(spec.cylinder_front)
    axis = rig.point_mm(0.74 * rig.width, 0.745 * rig.height, z_front + r)
    half_h = 0.5 * 0.39 * rig.height * z_front * rig.pitch_mm / rig.focal_length_mm
    angles = np.radians(np.linspace(-75.0, 75.0, CYLINDER_FACETS + 1))
    facets = []
    for k in range(CYLINDER_FACETS):
        a0, a1 = angles[k], angles[k + 1]
        p0 = axis + r * np.array([np.sin(a0), 0.0, -np.cos(a0)])
        p1 = axis + r * np.array([np.sin(a1), 0.0, -np.cos(a1)])
        chord = p1 - p0
        length = float(np.linalg.norm(chord))
        facets.append(
            _plane(
                rig,
                f"cylinder_{k}",
                0.5 * (p0 + p1),
                chord / length,
                np.array([0, 1.0, 0]),
                (0.5 * length * 1.001, half_h),
                seed=seed + k,
                albedo=(0.8, 0.95, 0.8),
            )
        )
    return facets


def relief_scene(
    rig: QuadRig | None = None, *, spec: ReliefSpec = ReliefSpec(), seed: int = 0
) -> QuadScene:
    """Back wall, three steps, a slanted plane and a cylinder, seen by ``rig`` (nearest first).

    Boxes are fractions of the centre view; the wall fills everything behind.
    """
    rig = QuadRig() if rig is None else rig
    regions: list[Region] = []
    for i, d in enumerate(spec.steps):
        x0 = 0.05 + i * 0.13
        regions.append(
            _fronto(
                rig,
                f"step_{i}",
                d,
                (x0, 0.06, x0 + 0.13, 0.46),
                seed=seed + 1 + i,
                albedo=(0.95, 0.85, 0.7),
            )
        )
    regions.append(_slanted(rig, spec.slant, seed=seed + 10))
    regions += _cylinder(rig, spec, seed=seed + 20)
    regions.sort(key=lambda reg: float(reg.plane.origin[2]))
    regions.append(
        _fronto(
            rig, "wall", spec.wall, (-0.6, -0.6, 1.6, 1.6), seed=seed + 60, albedo=(0.85, 0.95, 1.0)
        )
    )
    return QuadScene(rig, regions)


def _rays(rig: QuadRig, xs: FloatArray, ys: FloatArray) -> FloatArray:
    cx, cy = rig.intrinsics.principal_point
    return np.stack(
        [
            (xs - cx) * rig.pitch_mm,
            (ys - cy) * rig.pitch_mm,
            np.full(xs.shape, rig.focal_length_mm),
        ],
        -1,
    )


def cast(
    scene: QuadScene,
    xs: FloatArray,
    ys: FloatArray,
    *,
    origin_mm: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> tuple[FloatArray, NDArray[np.intp]]:
    """Depth (mm along +z) and region index seen at continuous pixels from a camera at ``origin``.

    The camera looks along +z with the rig's intrinsics; -1 / inf where nothing is hit.
    """
    d = _rays(scene.rig, np.asarray(xs, np.float64), np.asarray(ys, np.float64))
    best, label = nearest_hits(scene.regions, d, np.asarray(origin_mm, dtype=np.float64))
    return best * scene.rig.focal_length_mm, label


def depth_map(
    scene: QuadScene, camera: int, *, carriage_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
) -> NDArray[np.float32]:
    """True depth (mm) at every pixel centre of one camera, ``(H, W)`` float32; inf = nothing."""
    rig = scene.rig
    px, py = rig.positions[camera]
    origin = (
        rig.baseline_mm * px + carriage_mm[0],
        rig.baseline_mm * py + carriage_mm[1],
        carriage_mm[2],
    )
    ys, xs = np.mgrid[0 : rig.height, 0 : rig.width] + 0.5
    depth, _ = cast(scene, xs, ys, origin_mm=origin)
    return depth.astype(np.float32)


def surface_cloud(
    scene: QuadScene,
    *,
    step_px: float = 1.0,
    margin_px: float = 16.0,
    carriage_mm: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> PointCloud:
    """The true surface seen by the virtual centre camera, one point every ``step_px``.

    Points within ``margin_px`` of the image border are left out (the tile processor
    measures no tile there). Colour: each region's albedo. Coordinates are in the frame
    of the virtual centre camera after the carriage moved by ``carriage_mm``.
    """
    rig = scene.rig
    xs1 = np.arange(margin_px, rig.width - margin_px + 1e-9, step_px)
    ys1 = np.arange(margin_px, rig.height - margin_px + 1e-9, step_px)
    xs, ys = np.meshgrid(xs1, ys1)
    depth, label = cast(scene, xs, ys, origin_mm=carriage_mm)
    ok = np.isfinite(depth)
    s = depth[ok] * rig.pitch_mm / rig.focal_length_mm
    cx, cy = rig.intrinsics.principal_point
    xyz = np.stack([(xs[ok] - cx) * s, (ys[ok] - cy) * s, depth[ok]], 1).astype(np.float32)
    albedo = np.array([r.plane.albedo_rgb for r in scene.regions])
    rgb = np.round(np.clip(albedo[label[ok]], 0, 1) * 255).astype(np.uint8)
    return PointCloud(xyz, np.ones(len(xyz), np.float32), rgb)


def render_quad_at(
    scene: QuadScene,
    carriage_mm: tuple[float, float, float] = (0.0, 0.0, 0.0),
    *,
    exposure_us: float = 70000.0,
    model: SensorModel = DEFAULT_SENSOR,
    seed: int | None = 0,
    scale: int = 1,
) -> NDArray[np.uint16]:
    """The four raw images ``(4, H, W)`` with the quad moved by ``carriage_mm``.

    ``scale`` renders a sensor with ``scale`` times the pixels per axis and 1/scale the
    pitch (the same field of view): the directly rendered high-resolution upper bound.
    """
    rig = scene.rig
    intr = rig.intrinsics
    if scale != 1:
        intr = Intrinsics(
            rig.focal_length_mm, rig.pixel_pitch_um / scale, rig.width * scale, rig.height * scale
        )
    world = World(scene.scene)
    rng = None if seed is None else np.random.default_rng(seed)
    out = []
    for cam in range(4):
        px, py = rig.positions[cam]
        pose = Pose.at(
            (
                rig.baseline_mm * px + carriage_mm[0],
                rig.baseline_mm * py + carriage_mm[1],
                carriage_mm[2],
            )
        )
        rgb = render_radiance(world, intr, pose)
        out.append(expose(mosaic(rgb, rig.bayer), exposure_us=exposure_us, model=model, rng=rng))
    return np.stack(out)


def write_truth(
    path: str | Path,
    scene: QuadScene,
    *,
    step_px: float = 1.0,
    carriage_mm: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> dict[str, str]:
    """Write ``reference.ply`` (the dense true surface) and ``depth_cam0..3.tif`` (mm, float32).

    Both for the quad after the carriage moved by ``carriage_mm``.
    """
    root = Path(path)
    root.mkdir(parents=True, exist_ok=True)
    cloud = surface_cloud(scene, step_px=step_px, carriage_mm=carriage_mm)
    ply = write_ply(root / "reference.ply", cloud, comments=("elphel-sim: true surface, mm",))
    out = {"reference": str(ply)}
    for cam in range(4):
        file = root / f"depth_cam{cam}.tif"
        with replacing(file, keep_suffix=True) as tmp:
            depth = depth_map(scene, cam, carriage_mm=carriage_mm)
            tifffile.imwrite(tmp, depth, metadata={"unit": "mm", "camera": cam})
        out[f"depth_cam{cam}"] = str(file)
    return out


def burst_positions_mm(rig: QuadRig, *, scale: int = 2, disparity_px: float = 2.5) -> list[float]:
    """Carriage positions of a sub-pixel burst planned for a surface at ``disparity_px``.

    `elphel burst plan --bayer` for the rig's optics at that surface's depth.
    """
    from elphel_host.burst.plan import plan_burst

    plan = plan_burst(
        scale=scale,
        focal_length_mm=rig.focal_length_mm,
        pixel_pitch_um=rig.pixel_pitch_um,
        distance_mm=rig.depth_mm(disparity_px),
        bayer=rig.bayer is not None,
    )
    return [float(p) for p in plan.positions_mm]


def simulate_quad_burst(
    path: str | Path,
    scene: QuadScene,
    positions_mm: Sequence[float],
    *,
    axis_angle_deg: float,
    seed: int = 0,
    model: SensorModel = DEFAULT_SENSOR,
) -> Path:
    """Render the quad at each carriage position along the axis; write a quad-burst directory.

    Frame k of every camera is taken with the carriage at ``positions_mm[k]`` (one
    trigger); each frame entry records ``stage_mm`` and ``caliper_mm`` (exact here), the
    bursts' manifests the stage axis angle.
    """
    from elphel_host.burst.io import write_quad_burst

    rig = scene.rig
    t = np.radians(axis_angle_deg)
    frames = []
    for k, s in enumerate(positions_mm):
        offset = (float(s * np.cos(t)), float(s * np.sin(t)), 0.0)
        frames.append(render_quad_at(scene, offset, seed=seed + 1000 * k, model=model))
    stack = np.stack(frames, axis=1)  # (4, N, H, W)
    infos = [
        {"stage_mm": float(s), "caliper_mm": float(s), "timestamp_ns": 10_000_000 * k}
        for k, s in enumerate(positions_mm)
    ]
    return write_quad_burst(
        path,
        stack,
        positions=rig.positions,
        infos=infos,
        bayer=rig.bayer,
        optics={
            "focal_length_mm": rig.focal_length_mm,
            "pixel_pitch_um": rig.pixel_pitch_um,
            "baseline_mm": rig.baseline_mm,
        },
        stage={"axis_angle_deg": float(axis_angle_deg)},
        full_scale_dn=float((1 << model.bits) - 1),
    )
