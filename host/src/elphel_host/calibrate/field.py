"""Field ("lazy eye") calibration: small drifts of a quad's cameras, from ordinary scenes.

A rig warms, bends and its lenses' focal lengths change with temperature: each camera
turns a little (tilt about its x axis, azimuth about y, roll about z) and zooms. The
tile processor then places each camera's tiles a fraction of a pixel (or a few pixels)
off, and every pair's correlation peak moves off lag 0 (:mod:`.mismatch`).

Model. Camera 0 defines the rig's frame and stays as calibrated (the virtual camera
looks along its axis); cameras 1-3 each get 4 corrections ``(tilt, azimuth, roll,
zoom)``: ``R <- Q R``, ``t <- Q t`` (the camera turns about its own centre, Q the
rotation by ``(tilt, azimuth, roll)`` in its frame) and ``fx, fy <- (1 + zoom) fx, fy``.
How each tile's pixel in camera i moves per unit of each correction is found by finite
differences through the calibrated projection (:class:`~elphel_host.tp.calibrated.
CalibratedGeometry`), at the tile's target disparity. A tile's pair offsets
``m_ab = e_b - e_a`` are then linear in the 12 corrections plus the tile's unknown
residual disparity, which moves camera i by ``g_i`` (the projection's derivative by the
disparity). Each tile's disparity is eliminated from its 12 equations, so near tiles
give only what disparity cannot explain; tiles at infinity (the farthest cluster of
disparities, within ``infinity_band_px``) keep their disparity at 0 and fix the one
combination the others cannot see (all cameras moving as a disparity would). The
equations are weighted by each peak's strength (squared), outliers beyond 4 robust
standard deviations dropped, and solved by weighted least squares; the calibration is
updated, every quad measured again with it, and so on until every camera's mismatch is below
``tolerance_px``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from elphel_host.calibrate.camera_model import CameraModel, rotation_matrix, rotation_vector
from elphel_host.calibrate.mismatch import PairOffsets, pair_offsets
from elphel_host.errors import InputFormatError
from elphel_host.tp.calibrated import CalibratedGeometry
from elphel_host.tp.config import DEFAULT_CONFIG, TpConfig
from elphel_host.tp.geometry import QuadGeometry
from elphel_host.tp.images import QuadImages
from elphel_host.tp.processor import disparity_map

F64 = NDArray[np.float64]
Camera = tuple[CameraModel, F64, F64]

#: The corrections of each camera 1-3, in order (radians, radians, radians, relative).
CORRECTIONS = ("tilt", "azimuth", "roll", "zoom")
_STEP = 1e-4  # finite-difference step of a correction
_MIN_STRENGTH = 0.15  # weaker peaks are texture-less or occluded
_MIN_TILES = 50


@dataclass(frozen=True)
class FieldResult:
    """What :func:`refine_extrinsics` found.

    Attributes
    ----------
    cameras
        The updated cameras (lens, R, t_mm), camera 0 first, as calibration.json has them.
    corrections
        ``(4, 4)``: per camera the total (tilt, azimuth, roll, zoom) applied (camera 0 zero).
    mismatch_before_px, mismatch_after_px
        ``(4,)``: per camera, RMS over the used tiles of the pixel offset of its image
        from the four cameras' mean: before, that of all the drift found (at the first
        measurement's tiles); after, that of the drift the last measurement still finds.
    scatter_px
        RMS of the pair offsets left after the final fit (measurement noise).
    iterations
        Measurements and updates made.
    tiles, infinity_tiles
        Tiles used in the final fit, and of them the tiles taken as at infinity.
    """

    cameras: tuple[Camera, ...]
    corrections: F64
    mismatch_before_px: F64
    mismatch_after_px: F64
    scatter_px: float
    iterations: int
    tiles: int
    infinity_tiles: int


def pixels_per_unit(lens: CameraModel) -> F64:
    """Pixels per unit of each correction (tilt, azimuth, roll, zoom).

    Tilt and azimuth at the image's centre (the focal length along y and x), roll and zoom
    at its corner (half the diagonal).
    """
    half_diagonal_px = float(np.hypot(lens.width, lens.height)) / 2
    return np.array([lens.fy, lens.fx, half_diagonal_px, half_diagonal_px])


def apply_corrections(cameras: Sequence[Camera], corrections: F64) -> tuple[Camera, ...]:
    """Cameras turned and zoomed by ``corrections`` ``(4, 4)`` (module docstring)."""
    out = []
    for (lens, rot, t_mm), (tilt, azimuth, roll, zoom) in zip(cameras, corrections, strict=True):
        q = rotation_matrix(np.array([tilt, azimuth, roll]))
        zoomed = replace(lens, fx=lens.fx * (1 + zoom), fy=lens.fy * (1 + zoom))
        out.append((zoomed, q @ rot, q @ t_mm))
    return tuple(out)


def _moved(geometry: CalibratedGeometry, cam: int, k: int, h: float) -> CalibratedGeometry:
    """The geometry with camera ``cam``'s correction ``k`` changed by ``h``."""
    if k < 3:
        vec = np.zeros(3)
        vec[k] = h
        rotations = geometry.rotations.copy()
        rotations[cam] = rotation_matrix(vec) @ rotations[cam]
        return replace(geometry, rotations=rotations)
    lenses = list(geometry.lenses)
    lens = lenses[cam]
    lenses[cam] = replace(lens, fx=lens.fx * (1 + h), fy=lens.fy * (1 + h))
    return replace(geometry, lenses=tuple(lenses))


def camera_jacobians(geometry: CalibratedGeometry, offsets: PairOffsets) -> tuple[F64, F64]:
    """Per tile the pixels each camera moves by, per correction and per unit of disparity.

    Returns ``(T, 4, 4, 2)`` (camera, correction, x/y; camera 0 zero) and ``(T, 4, 2)``.
    """
    n = offsets.target.size
    jac = np.zeros((n, 4, len(CORRECTIONS), 2))
    args = (offsets.cx, offsets.cy, offsets.target)
    for cam in range(1, 4):
        for k in range(len(CORRECTIONS)):
            hi = _moved(geometry, cam, k, _STEP).pixels(cam, *args)
            lo = _moved(geometry, cam, k, -_STEP).pixels(cam, *args)
            jac[:, cam, k] = np.stack([hi[0] - lo[0], hi[1] - lo[1]], -1) / (2 * _STEP)
    gain = np.zeros((n, 4, 2))
    for cam in range(4):
        hi = geometry.pixels(cam, offsets.cx, offsets.cy, offsets.target + 0.5)
        lo = geometry.pixels(cam, offsets.cx, offsets.cy, offsets.target - 0.5)
        gain[:, cam] = np.stack([hi[0] - lo[0], hi[1] - lo[1]], -1)
    return jac, gain


@dataclass(frozen=True, eq=False)
class TileEquations:
    """The stacked equations of every tile: ``m = A x + u D`` with weights ``w``.

    ``design`` ``(T, 12, 12)`` (pair component by correction of cameras 1-3),
    ``disparity`` ``(T, 12)``, ``measured`` ``(T, 12)``, ``weight`` ``(T, 12)``,
    ``target`` ``(T,)``; ``camera_design`` ``(T, 4, 2, 12)``: each camera's pixel offset
    per correction (for the mismatch figures).
    """

    design: F64
    disparity: F64
    measured: F64
    weight: F64
    target: F64
    camera_design: F64


def tile_equations(
    geometry: CalibratedGeometry, offsets: PairOffsets, pairs: Sequence[tuple[int, int]]
) -> TileEquations:
    """The equations of one quad's tiles (module docstring)."""
    jac, gain = camera_jacobians(geometry, offsets)
    n = offsets.target.size
    cam_design = np.zeros((n, 4, 2, 12))
    for cam in range(1, 4):
        cam_design[:, cam, :, (cam - 1) * 4 : cam * 4] = jac[:, cam].transpose(0, 2, 1)
    design = np.stack([cam_design[:, b] - cam_design[:, a] for a, b in pairs], 1)
    disparity = np.stack([gain[:, b] - gain[:, a] for a, b in pairs], 1)
    s = offsets.strength
    weight = np.where(np.isfinite(s) & (s >= _MIN_STRENGTH), s * s, 0.0)
    measured = np.nan_to_num(offsets.offsets_px)
    return TileEquations(
        design.reshape(n, -1, 12),
        disparity.reshape(n, -1),
        measured.reshape(n, -1),
        np.repeat(weight, 2, axis=1),
        offsets.target,
        cam_design,
    )


def _concat(parts: Sequence[TileEquations]) -> TileEquations:
    fields = TileEquations.__dataclass_fields__
    return TileEquations(*(np.concatenate([getattr(p, f) for p in parts]) for f in fields))


def _fit_disparity(eq: TileEquations, x: F64, weight: F64) -> F64:
    """Per tile, the residual disparity that best explains what ``x`` leaves."""
    rest = eq.measured - eq.design @ x
    den = (weight * eq.disparity**2).sum(1)
    fitted = (weight * eq.disparity * rest).sum(1) / np.where(den > 0, den, 1.0)
    out: F64 = np.where(den > 0, fitted, 0.0)
    return out


def _solve(eq: TileEquations, weight: F64, infinity: NDArray[np.bool_]) -> F64:
    """Weighted least squares of the 12 corrections, each tile's disparity eliminated."""
    normal, rhs = normal_equations(eq, weight, infinity)
    x: F64 = np.asarray(np.linalg.lstsq(normal, rhs, rcond=1e-10)[0], dtype=np.float64)
    return x


def normal_equations(
    eq: TileEquations, weight: F64, infinity: NDArray[np.bool_]
) -> tuple[F64, F64]:
    """Normal equations ``(12, 12)``, ``(12,)`` of the corrections, tile disparities eliminated."""
    wu = weight * eq.disparity
    den = (wu * eq.disparity).sum(1)
    free = (den > 0) & ~infinity
    # P = W - (W u)(W u)^T / (u^T W u) for tiles of unknown disparity, W at infinity
    proj = weight[:, :, None] * np.eye(weight.shape[1])
    proj[free] -= wu[free, :, None] * wu[free, None, :] / den[free, None, None]
    known = eq.measured + np.where(infinity, eq.target, 0.0)[:, None] * eq.disparity
    at_p = eq.design.transpose(0, 2, 1) @ proj
    normal: F64 = (at_p @ eq.design).sum(0)
    rhs: F64 = (at_p @ known[:, :, None])[..., 0].sum(0)
    return normal, rhs


def _infinity_tiles(eq: TileEquations, x: F64, weight: F64, band_px: float) -> NDArray[np.bool_]:
    """Tiles whose disparity lies within ``band_px`` of the farthest (2nd percentile) tiles."""
    used = (weight > 0).sum(1) >= 6
    disparity = eq.target + _fit_disparity(eq, x, weight)
    if used.sum() < _MIN_TILES:
        return np.zeros(len(used), dtype=bool)
    far = float(np.percentile(disparity[used], 2))
    out: NDArray[np.bool_] = used & (disparity <= far + band_px)
    return out


def robust_solve(eq: TileEquations, band_px: float) -> tuple[F64, F64, NDArray[np.bool_]]:
    """Corrections ``(12,)``, the final weights and the infinity tiles (outliers dropped)."""
    weight = eq.weight.copy()
    infinity = np.zeros(len(weight), dtype=bool)
    x = _solve(eq, weight, infinity)
    for _ in range(3):
        infinity = _infinity_tiles(eq, x, weight, band_px)
        x = _solve(eq, weight, infinity)
        d = np.where(infinity, -eq.target, _fit_disparity(eq, x, weight))
        rest = eq.measured - eq.design @ x - d[:, None] * eq.disparity
        norm = np.hypot(rest[:, 0::2], rest[:, 1::2])
        sigma = 1.4826 * float(np.median(norm[eq.weight[:, 0::2] > 0]))
        keep = np.repeat(norm <= 4 * max(sigma, 1e-3), 2, axis=1)
        weight = np.where(keep, eq.weight, 0.0)
    return x, weight, infinity


def camera_mismatch_px(eq: TileEquations, x: F64, weight: F64) -> F64:
    """Per camera, RMS over the weighted tiles of its drift's offset from the cameras' mean."""
    moved = eq.camera_design @ x  # (T, 4, 2)
    rel = moved - moved.mean(axis=1, keepdims=True)
    w = weight.sum(1)
    out: F64 = np.sqrt((w[:, None] * (rel**2).sum(-1)).sum(0) / max(w.sum(), 1e-12))
    return out


def _scatter_px(eq: TileEquations, x: F64, weight: F64, infinity: NDArray[np.bool_]) -> float:
    d = np.where(infinity, -eq.target, _fit_disparity(eq, x, weight))
    rest = eq.measured - eq.design @ x - d[:, None] * eq.disparity
    return float(np.sqrt((weight * rest**2).sum() / max(weight.sum(), 1e-12) * 2))


def measure_quad(
    quad: QuadImages,
    geometry: CalibratedGeometry,
    *,
    config: TpConfig = DEFAULT_CONFIG,
    search_px: int = 2,
) -> TileEquations:
    """One quad's equations: its DSI with ``geometry``, then its pairs' 2-D peaks there.

    Raises
    ------
    InputFormatError
        The images are of another size than the calibration (the message names both).
    """
    placed = placed_quad(quad, geometry)
    dsi = disparity_map(placed, config=config)
    return dsi_equations(placed, dsi["disparity"], config=config, search_px=search_px)


def placed_quad(quad: QuadImages, geometry: CalibratedGeometry) -> QuadImages:
    """``quad`` with ``geometry`` as its calibration."""
    return replace(
        quad, geometry=QuadGeometry(positions=quad.geometry.positions, calibration=geometry)
    )


def dsi_equations(
    placed: QuadImages,
    disparity: NDArray[np.floating],
    *,
    config: TpConfig = DEFAULT_CONFIG,
    search_px: int = 2,
) -> TileEquations:
    """The equations of a quad whose DSI (``disparity``) was made with its calibration.

    ``placed``: the quad with the calibration to refine (:func:`placed_quad`).
    """
    geometry = placed.geometry.calibration
    if not isinstance(geometry, CalibratedGeometry):
        raise ValueError("the quad has no calibration; allowed: a quad placed by placed_quad")
    target = np.nan_to_num(np.asarray(disparity, dtype=np.float64))
    target = np.clip(target, config.min_disparity, None)
    offsets = pair_offsets(placed, target, config=config, search_px=search_px)
    return tile_equations(geometry, offsets, placed.geometry.pairs)


def total_corrections(initial: Sequence[Camera], final: Sequence[Camera]) -> F64:
    """Per camera the corrections that turn ``initial`` into ``final``."""
    out = np.zeros((4, len(CORRECTIONS)))
    for cam, ((lens0, r0, _), (lens1, r1, _)) in enumerate(zip(initial, final, strict=True)):
        out[cam, :3] = rotation_vector(r1 @ r0.T)
        out[cam, 3] = lens1.fx / lens0.fx - 1
    return out


def refine_extrinsics(
    quads: Sequence[QuadImages],
    cameras: Sequence[Camera],
    *,
    iterations: int = 8,
    tolerance_px: float = 0.002,
    infinity_band_px: float = 0.15,
    first_search_px: int = 6,
    config: TpConfig = DEFAULT_CONFIG,
) -> FieldResult:
    """Estimate and remove the drift of cameras 1-3 from ordinary scenes (module docstring).

    Parameters
    ----------
    quads
        Image sets of the quad (any scenes with texture; part of them at infinity).
    cameras
        The calibration's cameras (lens, R, t_mm), camera 0 first.
    iterations
        Most updates; each is followed by a new measurement of every quad.
    tolerance_px
        Stop when every camera's mismatch is below this.
    infinity_band_px
        Tiles within this of the farthest disparities are taken as at infinity.
    first_search_px
        How far (px) the first measurement searches each pair's peak (the drift's reach).
    config
        The tile processor's options.

    Raises
    ------
    InputFormatError
        No quads, images of another size than the calibration, or fewer than 50 tiles
        with texture.
    """
    if not quads:
        raise InputFormatError("no quad image sets; allowed: at least one")
    if iterations < 1 or tolerance_px <= 0 or infinity_band_px <= 0:
        raise ValueError(
            f"iterations={iterations}, tolerance_px={tolerance_px}, "
            f"infinity_band_px={infinity_band_px}; allowed: >= 1, > 0, > 0"
        )
    current = tuple(cameras)
    found = np.zeros(3 * len(CORRECTIONS))  # the drift found so far, applied or not
    first: list[tuple[TileEquations, F64]] = []  # the first measurement, for "before"
    search = first_search_px
    for it in range(iterations + 1):
        geometry = CalibratedGeometry.from_cameras(current)
        eq = _concat([measure_quad(q, geometry, config=config, search_px=search) for q in quads])
        check_texture(eq)
        x, weight, infinity = robust_solve(eq, infinity_band_px)
        found += x
        first += [] if first else [(eq, weight)]
        mismatch = camera_mismatch_px(eq, x, weight)
        if it == iterations or mismatch.max() < tolerance_px:
            break
        step = np.zeros((4, len(CORRECTIONS)))
        step[1:] = x.reshape(3, len(CORRECTIONS))
        current = apply_corrections(current, step)
        search = 2
    return FieldResult(
        cameras=current,
        corrections=total_corrections(cameras, current),
        mismatch_before_px=camera_mismatch_px(first[0][0], found, first[0][1]),
        mismatch_after_px=mismatch,
        scatter_px=_scatter_px(eq, x, weight, infinity),
        iterations=it,
        tiles=int(((weight > 0).sum(1) >= 6).sum()),
        infinity_tiles=int(infinity.sum()),
    )


def check_texture(eq: TileEquations) -> None:
    """Refuse equations with fewer than 50 textured tiles (InputFormatError says what to do)."""
    textured = int(((eq.weight > 0).sum(1) >= 6).sum())
    if textured < _MIN_TILES:
        raise InputFormatError(
            f"{textured} tiles with texture (pair correlation >= {_MIN_STRENGTH}) in all "
            f"quads; allowed: at least {_MIN_TILES}: use scenes with detail (not sky, not "
            "blank walls), part of them far away"
        )
