"""`elphel depth`: fuse each camera's burst of a quad burst, then the tile processor and depth.

Stages, each timed:

1. ``prior``: the tile processor on frame 0 of the four cameras (the low-resolution quad,
   Bayer as captured): the disparity map that predicts each surface's parallax.
2. ``fuse``: each camera's burst fused at ``scale``. With ``motion="local"`` a frame's
   shift at a pixel is ``D(p) * v_k`` (:mod:`elphel_host.mfsr.local_motion`), D the
   prior moved into the camera's view and ``v_k`` from the caliper positions and the
   stage axis (else from the global registration), and the samples are fused by
   shift-and-add; with ``motion="global"`` one shift per frame and ``elphel mfsr``'s
   ``method``.
3. ``tp``: the tile processor on the fused quad (colour fused to luminance with the
   correlation's colour weights), disparities in fused pixels and, in the
   ``disparity_lr`` layer, in original pixels.
4. ``depth``: depth map (mm) and point cloud from the geometry's optics, the fused pitch
   being the original divided by ``scale``.

A quad burst whose quad.json names a calibration holds the cameras' raw images: the
prior runs on them with the calibrated geometry, each camera's parallax map is the
centre view's moved into its raw view (:mod:`elphel_host.depth.raw_views`), and the
fused quad's geometry is the calibration up-sampled by ``scale``
(:func:`elphel_host.tp.calibrated.scaled`: MFSR puts the original pixel i at
``scale * i + (scale - 1) / 2``); depth comes from the calibration's focal length and
baseline.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elphel_host import strict_json
from elphel_host.burst.io import QuadBurst, read_quad_burst
from elphel_host.depth.geometry import DepthOptics
from elphel_host.depth.products import (
    DEFAULT_MAX_DISAGREEMENT,
    DEFAULT_MIN_STRENGTH,
    DepthResult,
    dsi_depth,
)
from elphel_host.depth.raw_views import (
    calibration_document,
    motion_direction,
    raw_view,
)
from elphel_host.errors import InputFormatError
from elphel_host.fileio import write_atomic
from elphel_host.mfsr.bayer import bayer_luma
from elphel_host.mfsr.fuse import fuse_frames, register_lumas
from elphel_host.mfsr.local_motion import (
    ParallaxModel,
    camera_view_disparity,
    disparity_field,
    fuse_parallax,
    pixel_disparity,
)
from elphel_host.mfsr.scale import check_scale
from elphel_host.tp.calibrated import CALIBRATION_FILE, CalibratedGeometry, scaled
from elphel_host.tp.config import TpConfig
from elphel_host.tp.geometry import QuadGeometry
from elphel_host.tp.images import QuadImages
from elphel_host.tp.io import QuadManifest, quad_cameras, write_quad_dir
from elphel_host.tp.processor import disparity_map

F32 = NDArray[np.float32]
MOTIONS = ("local", "global")
SHIFT_AND_ADD = "shift-and-add"  # the fusion of local motion
#: Luminance of a fused colour image: the correlation's colour weights (R, G, B).
LUMA_WEIGHTS = (0.294, 0.588, 0.118)


@dataclass(frozen=True)
class DepthConfig:
    """Options of :func:`quad_burst_depth`.

    Attributes
    ----------
    scale
        Up-sampling factor of the fusion (1..8).
    method
        Fusion method of ``motion="global"`` (``robust``, ``baseline``, ``bicubic``, as
        `elphel mfsr`); ``bicubic`` up-samples the first frames with either motion.
    motion
        ``local`` (per-pixel parallax from the disparity prior, shift-and-add) or
        ``global`` (one shift per frame).
    min_strength
        Strength threshold of the depth map and cloud (the same for every method).
    max_disagreement
        Tiles whose combined disparity is farther than this fraction from the median of
        their confident per-direction ones are left out of the depth map and cloud
        (None: kept).
    threads
        Worker threads of the tile processor and the fusion.
    """

    scale: int = 2
    method: str = "robust"
    motion: str = "local"
    min_strength: float = DEFAULT_MIN_STRENGTH
    max_disagreement: float | None = DEFAULT_MAX_DISAGREEMENT
    threads: int = 2

    @property
    def fusion(self) -> str:
        """What fuses the bursts: ``shift-and-add`` (local motion) or the method."""
        local = self.motion == "local" and self.method != "bicubic"
        return SHIFT_AND_ADD if local else self.method

    def __post_init__(self) -> None:
        check_scale(self.scale)
        if self.motion not in MOTIONS:
            raise ValueError(f"motion={self.motion!r}; allowed: {', '.join(MOTIONS)}")
        if not self.min_strength >= 0:
            raise ValueError(f"min_strength={self.min_strength}; allowed: >= 0")
        if self.max_disagreement is not None and not self.max_disagreement > 0:
            raise ValueError(f"max_disagreement={self.max_disagreement}; allowed: > 0 or None")


def tp_config(scale: float, *, threads: int = 2, calibrated: bool = False) -> TpConfig:
    """The tile processor's options for a quad up-sampled by ``scale``.

    Disparities grow with the scale; the first pass also tries a target of 7 px when the
    scale is above 1 so that surfaces beyond the +-7 px search still lock, and a second
    refinement pass follows. A calibrated quad's fused images take four refinement
    passes: each pass leaves a fraction of the residual (the correlation's pull towards
    its target), and a plane whose disparity lies between the targets 0 and 7 comes out
    0.5 % near after two passes, 0.01 % after four.
    """
    if scale <= 1:
        return TpConfig(threads=threads)
    return TpConfig(threads=threads, scan=(0.0, 7.0), refine_passes=4 if calibrated else 2)


def luminance(rgb: F32) -> F32:
    """``(H, W, 3)`` -> ``(H, W)`` with :data:`LUMA_WEIGHTS`."""
    w = np.asarray(LUMA_WEIGHTS, dtype=np.float32) / np.float32(sum(LUMA_WEIGHTS))
    out: F32 = np.asarray(rgb, dtype=np.float32) @ w
    return out


@dataclass(frozen=True, eq=False)
class DepthRun:
    """What :func:`quad_burst_depth` computed.

    Attributes
    ----------
    prior_dsi, dsi
        The low-resolution DSI (frame 0) and the fused quad's DSI.
    fused
        The fused quad (luminance, full scale 1) the DSI was measured on.
    fused_rgb
        The fused colour images ``(4, H, W, 3)`` (None for mono bursts).
    depth
        Depth map and cloud.
    optics
        The fused quad's optics.
    seconds
        Per stage (``prior``, ``fuse``, ``tp``, ``depth``) and ``total``.
    info
        Per camera fusion details.
    """

    prior_dsi: dict[str, F32]
    dsi: dict[str, F32]
    fused: QuadImages
    fused_rgb: F32 | None
    depth: DepthResult
    optics: DepthOptics
    seconds: dict[str, float]
    info: dict[str, Any] = field(default_factory=dict)


def full_scale(qb: QuadBurst) -> float:
    if qb.manifest.full_scale_dn is not None:
        return float(qb.manifest.full_scale_dn)
    peak = max(float(b.frames.max()) for b in qb.bursts)
    return float(2 ** max(8, int(np.ceil(np.log2(peak + 1)))) - 1)


def parallax_model(qb: QuadBurst, cam: int, optics: DepthOptics) -> ParallaxModel | None:
    """The frames' shift per px of disparity from the caliper, or None without positions."""
    burst = qb.bursts[cam]
    pos = [e.position_mm for e in burst.infos]
    if any(p is None for p in pos):
        return None
    angle = float(burst.stage.get("axis_angle_deg", 0.0))
    return ParallaxModel.from_caliper(
        [float(p) for p in pos if p is not None],
        baseline_mm=optics.baseline_mm,
        axis_angle_deg=angle,
    )


def _fuse_camera(
    qb: QuadBurst,
    cam: int,
    lr: QuadImages,
    config: DepthConfig,
    centre: F32,
    median_disparity_px: float,
) -> tuple[F32, dict[str, Any]]:
    """One camera's burst fused as ``config.fusion`` says, and what the fusion reports.

    ``lr`` is the low-resolution quad (its geometry, calibrated or not, moves the
    disparity into the camera's view); ``centre`` is the centre view's disparity per
    pixel (for the shift-and-add fusion); ``median_disparity_px`` scales a parallax
    model found by registration when the burst has no stage positions.
    """
    burst = qb.bursts[cam]
    bayer = qb.manifest.bayer
    if config.fusion != SHIFT_AND_ADD:
        res = fuse_frames(
            [f.astype(np.float32) for f in burst.frames],
            scale=config.scale,
            method=config.method,
            bayer=bayer,
            prior=burst.stage_prior_px(),
        )
        return res.image, {"used": len(res.registrations) - len(res.excluded)}
    cam_info: dict[str, Any] = {"parallax_from": "caliper"}
    model = parallax_model(qb, cam, lr_optics(qb, lr.geometry))
    if model is None:
        frames = [f.astype(np.float32) for f in burst.frames]
        lumas = frames if bayer is None else [bayer_luma(f) for f in frames]
        regs = register_lumas(lumas, mosaic=bayer is not None)
        model = ParallaxModel.from_registration(regs, disparity_px=median_disparity_px)
        cam_info = {"parallax_from": "registration"}
    cal = lr.geometry.calibration
    if isinstance(cal, CalibratedGeometry):
        model, view = _raw_motion(
            model, cal, cam, centre, registered=cam_info["parallax_from"] == "registration"
        )
    else:
        view = camera_view_disparity(centre, lr.geometry.positions[cam])
    img, finfo = fuse_parallax(
        list(burst.frames), model, view, scale=config.scale, bayer=bayer, threads=config.threads
    )
    cam_info.update(finfo)
    return img, cam_info


def _raw_motion(
    model: ParallaxModel, cal: CalibratedGeometry, cam: int, centre: F32, *, registered: bool
) -> tuple[ParallaxModel, F32]:
    """A calibrated camera's parallax model and disparity map in its raw view.

    A model from the caliper is the virtual camera's: it is turned onto the raw view's
    direction (:class:`~elphel_host.depth.raw_views.RawView`). A model from registering
    this camera's own frames already carries its mean scale and direction: only the
    lens's variation about its mean is added to the map.
    """
    axis = motion_direction(model.per_disparity)
    view = raw_view(centre, cal, cam, direction=axis)
    if not registered:
        return view.model(model, axis), view.disparity
    return model, (view.disparity / np.median(view.gain)).astype(np.float32)


def lr_optics(qb: QuadBurst, geometry: QuadGeometry, *, source: str = "quad burst") -> DepthOptics:
    """The original images' optics: a calibrated quad's from its calibration, else quad.json's.

    A calibration gives the virtual camera's focal length and the square's side; the
    pixel pitch comes from quad.json ``optics`` when it is there (only ``f / pitch``
    matters).
    """
    cal = geometry.calibration
    if isinstance(cal, CalibratedGeometry):
        pitch = (qb.manifest.optics or {}).get("pixel_pitch_um")
        return cal.depth_optics(None if pitch is None else float(pitch))
    return DepthOptics.from_optics(qb.manifest.optics, source=f"{source}/quad.json")


def _geometries(
    qb: QuadBurst, calibration: CalibratedGeometry | None, scale: int, *, source: str
) -> tuple[QuadGeometry, QuadGeometry]:
    """The low-resolution quad's geometry and the fused quad's (calibration up-sampled)."""
    geometry = qb.manifest.geometry
    if calibration is None:
        if qb.manifest.calibration is not None:
            raise InputFormatError(
                f"{source}/quad.json names calibration={qb.manifest.calibration!r}, none was "
                "given; allowed: its calibrated geometry (read_and_run reads it)"
            )
        return geometry, geometry
    return (
        replace(geometry, calibration=calibration),
        replace(geometry, calibration=scaled(calibration, scale)),
    )


def _prior(
    qb: QuadBurst, geometry: QuadGeometry, full: np.float32, threads: int
) -> tuple[QuadImages, dict[str, F32]]:
    """The low-resolution quad (frame 0 of each camera) and its DSI."""
    lr = QuadImages(
        (np.stack([b.frames[0].astype(np.float32) for b in qb.bursts]) / full).astype(np.float32),
        bayer=qb.manifest.bayer,
        geometry=geometry,
    )
    return lr, disparity_map(lr, config=tp_config(1, threads=threads))


def _fuse_all(
    qb: QuadBurst,
    lr: QuadImages,
    prior: dict[str, F32],
    config: DepthConfig,
    full: np.float32,
    say: Callable[[str], None],
) -> tuple[F32, F32 | None, dict[str, Any]]:
    """Every camera fused: luminance ``(4, H S, W S)``, colour (None for mono), details."""
    field_lr = disparity_field(
        prior["disparity"], prior["strength"], min_strength=config.min_strength
    )
    centre = pixel_disparity(field_lr, lr.images.shape[1:])
    h, w = lr.images.shape[1:]
    hs, ws = h * config.scale, w * config.scale
    # the fused quad, filled camera by camera (no stacked copies: at 2592x1936 x2 the
    # colour planes alone take 1 GB)
    rgb = np.empty((4, hs, ws, 3), np.float32) if qb.manifest.bayer is not None else None
    lum = np.empty((4, hs, ws), np.float32)
    info: dict[str, Any] = {}
    median_px = float(np.median(field_lr))
    for cam, burst in enumerate(qb.bursts):
        say(f"fuse: camera {cam} ({burst.frames.shape[0]} frames, x{config.scale})")
        img, info[f"cam{cam}"] = _fuse_camera(qb, cam, lr, config, centre, median_px)
        img = np.asarray(img, dtype=np.float32)
        img /= full
        if rgb is not None:
            rgb[cam] = img
            lum[cam] = luminance(img)
        else:
            lum[cam] = img
        del img
    return lum, rgb, info


def quad_burst_depth(
    qb: QuadBurst,
    *,
    config: DepthConfig = DepthConfig(),
    calibration: CalibratedGeometry | None = None,
    source: str = "quad burst",
    progress: Callable[[str], None] | None = None,
) -> DepthRun:
    """Fuse every camera's burst, run the tile processor on the fused quad, make the depth.

    ``calibration``: the calibrated geometry of the raw images (the one quad.json names,
    required then; :func:`read_and_run` reads it). The fused quad's is the same
    up-sampled by the scale (:func:`elphel_host.tp.calibrated.scaled`), and the depth
    comes from its focal length and baseline.
    """
    say = progress or (lambda _msg: None)
    geo_lr, geo_hr = _geometries(qb, calibration, config.scale, source=source)
    optics = lr_optics(qb, geo_lr, source=source)
    full = np.float32(full_scale(qb))
    seconds: dict[str, float] = {}
    t_all = t0 = time.perf_counter()
    say("prior: tile processor on frame 0")
    lr, prior = _prior(qb, geo_lr, full, config.threads)
    seconds["prior"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    lum, rgb, info = _fuse_all(qb, lr, prior, config, full, say)
    seconds["fuse"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    say("tp: tile processor on the fused quad")
    fused = QuadImages(lum, bayer=None, geometry=geo_hr)
    calibrated = geo_hr.calibration is not None
    tp = tp_config(config.scale, threads=config.threads, calibrated=calibrated)
    dsi = disparity_map(fused, config=tp)
    dsi["disparity_lr"] = (dsi["disparity"] / np.float32(config.scale)).astype(np.float32)
    seconds["tp"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    hr_optics = optics.scaled(config.scale)
    depth = dsi_depth(
        dsi,
        fused,
        hr_optics,
        min_strength=config.min_strength,
        max_disagreement=config.max_disagreement,
        rgb_images=rgb,
    )
    seconds["depth"] = time.perf_counter() - t0
    seconds["total"] = time.perf_counter() - t_all
    return DepthRun(prior, dsi, fused, rgb, depth, hr_optics, seconds, info)


def read_and_run(
    path: str | Path, *, config: DepthConfig, progress: Callable[[str], None] | None = None
) -> tuple[DepthRun, float]:
    """Read a quad-burst directory and run :func:`quad_burst_depth`; also the read time."""
    t0 = time.perf_counter()
    qb = read_quad_burst(path)
    if qb.frames < 1:
        raise InputFormatError(f"{path}: the bursts have no frames")
    calibration = None
    if qb.manifest.calibration is not None:
        h, w = qb.bursts[0].frames.shape[1:]
        calibration = qb.manifest.calibration_of(Path(path), image_size=(w, h))
    run = quad_burst_depth(
        qb, config=config, calibration=calibration, source=str(path), progress=progress
    )
    return run, time.perf_counter() - t0


def write_fused_quad(path: str | Path, run: DepthRun) -> Path:
    """The fused quad as a quad directory (float32 luminance, full scale 1).

    A calibrated quad's fused quad carries its up-sampled calibration (calibration.json).
    """
    root = Path(path)
    cal = run.fused.geometry.calibration
    name = None
    if isinstance(cal, CalibratedGeometry):
        root.mkdir(parents=True, exist_ok=True)
        doc = (
            strict_json.dumps(
                calibration_document(cal), what="the fused quad's calibration", indent=1
            )
            + "\n"
        )
        write_atomic(root / CALIBRATION_FILE, doc.encode())
        name = CALIBRATION_FILE
    manifest = QuadManifest(
        cameras=quad_cameras(run.fused.geometry.positions),
        bayer=None,
        full_scale_dn=1.0,
        calibration=name,
        optics={
            "focal_length_mm": run.optics.focal_length_mm,
            "pixel_pitch_um": run.optics.pixel_pitch_um,
            "baseline_mm": run.optics.baseline_mm,
        },
    )
    return write_quad_dir(root, manifest, list(run.fused.images))
