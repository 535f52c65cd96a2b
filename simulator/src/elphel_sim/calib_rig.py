"""Cameras as a real rig has them, and the views of a checkerboard they take.

Each `RigCamera` has its own lens: OpenCV's rational model (`CameraModel`), a smooth
residual the model cannot express (`SmoothResidual`, pixels added after the model), a
space-variant Gaussian blur (sigma growing with the squared distance from the centre),
and its own small rotation and focal length. ``R``, ``t_mm`` map camera 0's frame into
the camera's (as calibration.json has them). The board (`PrintedBoard`) is posed in camera 0's frame
(``X0 = R_board @ Xb + t_board``) and may be bent (``warp_mm``, mrcal's two-parameter
deformation). `render_view` renders what each camera records (Bayer mosaic, shot and
read noise), `corner_truth` gives the true pixel of every corner and `write_views` writes
a views directory.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np
import tifffile
from numpy.typing import NDArray

from elphel_host.calibrate.camera_model import CameraModel, rotation_matrix
from elphel_host.tp import io as quad_format
from elphel_sim.calib_target import PrintedBoard, board_radiance
from elphel_sim.render import SensorModel, expose, mosaic

FloatArray = NDArray[np.float64]

#: A lens like Elphel's 4.5 mm on 2.2 um pixels, as the rational model (focal 0.79 widths).
BASE_DISTORTION = (-0.28, 0.09, 3e-4, -2e-4, -0.012, 0.05, 0.01, 0.002)
QUAD_POSITIONS = ((-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5))


@dataclass(frozen=True)
class SmoothResidual:
    """A smooth field of pixel offsets, a few low-frequency cosines over the image.

    ``terms`` rows are ``(axis, amplitude_px, kx, ky, phase)``: the offset along ``axis``
    (0 = x, 1 = y) adds ``amplitude_px * cos(pi * (kx * X + ky * Y) + phase)`` with X, Y
    the pixel position scaled to -1..1 over the image.
    """

    width: int
    height: int
    terms: tuple[tuple[int, float, float, float, float], ...] = ()

    @classmethod
    def random(cls, width: int, height: int, *, amplitude_px: float, seed: int) -> SmoothResidual:
        """Six terms whose amplitudes sum to at most ``amplitude_px`` per axis."""
        rng = np.random.default_rng(seed)
        terms = []
        for axis in (0, 1):
            amps = rng.uniform(0.5, 1.0, 3)
            amps *= amplitude_px / amps.sum()
            for a in amps:
                kx, ky = rng.uniform(-1.2, 1.2, 2)
                terms.append(
                    (axis, float(a), float(kx), float(ky), float(rng.uniform(0, 2 * np.pi)))
                )
        return cls(width, height, tuple(terms))

    def at(self, pixels: FloatArray) -> FloatArray:
        """The offsets ``(N, 2)`` at pixels ``(N, 2)``."""
        p = np.asarray(pixels, dtype=np.float64)
        xs = 2 * p[:, 0] / (self.width - 1) - 1
        ys = 2 * p[:, 1] / (self.height - 1) - 1
        out = np.zeros_like(p)
        for axis, amp, kx, ky, phase in self.terms:
            out[:, axis] += amp * np.cos(np.pi * (kx * xs + ky * ys) + phase)
        return out


@dataclass(frozen=True)
class RigCamera:
    """One camera of the rig: its lens, its residual, its blur and its pose from camera 0."""

    lens: CameraModel
    residual: SmoothResidual
    R: FloatArray = field(default_factory=lambda: np.eye(3))
    t_mm: FloatArray = field(default_factory=lambda: np.zeros(3))
    blur_centre_px: float = 0.7
    blur_edge_px: float = 1.1

    def project(self, points_cam0: FloatArray) -> FloatArray:
        """True pixels ``(N, 2)`` of points ``(N, 3)`` given in camera 0's frame."""
        local = np.asarray(points_cam0, dtype=np.float64) @ self.R.T + self.t_mm
        q = self.lens.project(local)
        return q + self.residual.at(q)

    def model_pixels(self, pixels: FloatArray) -> FloatArray:
        """Where the rational model alone puts what lands at ``pixels`` (residual removed)."""
        p = np.asarray(pixels, dtype=np.float64)
        q = p.copy()
        for _ in range(20):
            q = p - self.residual.at(q)
        return q

    def blur_px(self, xs: FloatArray, ys: FloatArray) -> FloatArray:
        """The PSF's sigma at pixels."""
        w, h = self.lens.width, self.lens.height
        cx, cy = self.lens.cx, self.lens.cy
        r2_max = max(cx, w - 1 - cx) ** 2 + max(cy, h - 1 - cy) ** 2
        r2 = (xs - cx) ** 2 + (ys - cy) ** 2
        out: FloatArray = (
            self.blur_centre_px + (self.blur_edge_px - self.blur_centre_px) * r2 / r2_max
        )
        return out


@dataclass(frozen=True)
class CalibRig:
    """Cameras (camera 0 first), their colour filter and their sensor's conversion."""

    cameras: tuple[RigCamera, ...]
    bayer: str | None = "GRBG"
    sensor: SensorModel = field(default_factory=SensorModel)
    exposure_us: float = 70000.0

    @property
    def size(self) -> tuple[int, int]:
        lens = self.cameras[0].lens
        return lens.width, lens.height


def make_rig(
    width: int = 640,
    height: int = 480,
    *,
    cameras: int = 4,
    baseline_mm: float = 150.0,
    residual_px: float = 0.0,
    blur_px: tuple[float, float] = (0.7, 1.1),
    seed: int = 0,
    bayer: str | None = "GRBG",
) -> CalibRig:
    """A rig of 1 to 4 cameras on a square of side ``baseline_mm`` (quad.json's positions).

    Each camera's focal length differs by up to 1 %, its principal point by up to 1 %
    of the width, its distortion by up to 10 % per coefficient, and it is turned by
    about 0.4 degrees about each axis; camera 0 defines the rig's frame.
    """
    if not 1 <= cameras <= 4:
        raise ValueError(f"cameras={cameras}; allowed: 1..4")
    rng = np.random.default_rng(seed)
    out = []
    for i in range(cameras):
        f = 0.79 * width * (1 + rng.uniform(-0.01, 0.01))
        lens = CameraModel(
            width,
            height,
            f,
            f * (1 + rng.uniform(-0.002, 0.002)),
            (width - 1) / 2 + rng.uniform(-0.01, 0.01) * width,
            (height - 1) / 2 + rng.uniform(-0.01, 0.01) * width,
            tuple(float(c * (1 + rng.uniform(-0.1, 0.1))) for c in BASE_DISTORTION),
        )
        residual = SmoothResidual.random(
            width, height, amplitude_px=residual_px, seed=seed * 10 + i
        )
        rot = np.eye(3) if i == 0 else rotation_matrix(rng.normal(0.0, np.radians(0.4), 3))
        centre = baseline_mm * (
            np.array([*QUAD_POSITIONS[i], 0.0]) - np.array([*QUAD_POSITIONS[0], 0.0])
        )
        out.append(RigCamera(lens, residual, rot, -rot @ centre, *blur_px))
    return CalibRig(tuple(out), bayer)


@dataclass(frozen=True)
class BoardPose:
    """A board's pose in camera 0's frame and its bend (``X0 = R @ Xb + t_mm``)."""

    R: FloatArray
    t_mm: FloatArray
    warp_mm: tuple[float, float] = (0.0, 0.0)


def board_points(
    board: PrintedBoard, xy_mm: FloatArray, warp_mm: tuple[float, float]
) -> FloatArray:
    """Points ``(N, 3)`` of the (bent) board at board-plane positions ``(N, 2)``.

    The bend is mrcal's: ``z = wx (1 - X^2) + wy (1 - Y^2)`` with X, Y the position scaled
    to -1..1 over the inner corners.
    """
    p = board.pattern
    xs = 2 * xy_mm[:, 0] / ((p.cols - 1) * p.square_mm) - 1
    ys = 2 * xy_mm[:, 1] / ((p.rows - 1) * p.square_mm) - 1
    z = warp_mm[0] * (1 - xs**2) + warp_mm[1] * (1 - ys**2)
    return np.column_stack([xy_mm[:, 0], xy_mm[:, 1], z])


def corner_truth(rig: CalibRig, board: PrintedBoard, pose: BoardPose) -> FloatArray:
    """True pixels ``(cameras, corners, 2)`` of the board's inner corners."""
    xy = board.pattern.object_points_mm()[:, :2]
    pts0 = board_points(board, xy, pose.warp_mm) @ pose.R.T + pose.t_mm
    return np.stack([cam.project(pts0) for cam in rig.cameras])


def _paper_window(
    cam: RigCamera, board: PrintedBoard, pose: BoardPose
) -> tuple[int, int, int, int]:
    """The pixel window ``(x0, y0, x1, y1)`` the paper and its blur may cover."""
    w, h = cam.lens.width, cam.lens.height
    outline = board.outline_mm()
    steps = np.linspace(0.0, 1.0, 17)[:, None]
    edge_b = np.concatenate(
        [outline[k] + (outline[(k + 1) % 4] - outline[k]) * steps for k in range(4)]
    )
    edge = board_points(board, edge_b[:, :2], pose.warp_mm) @ pose.R.T + pose.t_mm
    if np.any((edge @ cam.R.T + cam.t_mm)[:, 2] <= 0):
        return 0, 0, w, h
    p = cam.project(edge)
    if p.min() < -0.5 * w or p[:, 0].max() > 1.5 * w or p[:, 1].max() > 1.5 * h:
        return 0, 0, w, h  # far outside the view the model may fold: take every pixel
    m = 5 * max(cam.blur_centre_px, cam.blur_edge_px) + 3
    x0, y0 = (max(0, int(np.floor(c - m))) for c in p.min(axis=0))
    x1, y1 = (
        int(min(w, np.ceil(p[:, 0].max() + m) + 1)),
        int(min(h, np.ceil(p[:, 1].max() + m) + 1)),
    )
    return x0, y0, max(x0, x1), max(y0, y1)


def _board_coordinates(
    cam: RigCamera, board: PrintedBoard, pose: BoardPose, xs: FloatArray, ys: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Board coordinates in squares (u, v) at pixel centres ``xs, ys`` (2-D grids) of ``cam``."""
    pix = np.column_stack([xs.ravel(), ys.ravel()])
    rays = cam.lens.rays(cam.model_pixels(pix))
    m = cam.R @ pose.R  # board -> camera
    t = cam.R @ pose.t_mm + cam.t_mm
    centre = -m.T @ t
    d = np.column_stack([rays, np.ones(len(rays))]) @ m  # ray directions in the board's frame
    z_plane = np.zeros(len(rays))
    for _ in range(4):  # the bent board: intersect, lift to its height there, repeat
        s = (z_plane - centre[2]) / d[:, 2]
        hit = centre + s[:, None] * d
        z_plane = board_points(board, hit[:, :2], pose.warp_mm)[:, 2]
    hit[s <= 0] = np.nan
    sq = board.pattern.square_mm
    return (hit[:, 0] / sq + 1).reshape(xs.shape), (hit[:, 1] / sq + 1).reshape(xs.shape)


def _jacobian(u: FloatArray, v: FloatArray) -> FloatArray:
    ju_y, ju_x = np.gradient(u)
    jv_y, jv_x = np.gradient(v)
    return np.stack([np.stack([ju_x, ju_y], -1), np.stack([jv_x, jv_y], -1)], -2)


def render_grey(
    cam: RigCamera,
    board: PrintedBoard,
    pose: BoardPose,
    *,
    samples: int = 4,
    window: tuple[int, int, int, int] | None = None,
    extra_blur_px: float = 0.0,
) -> FloatArray:
    """The grey radiance one camera sees (background off the board's window).

    ``window`` ``(left, top, width, height)`` in the lens's pixels renders that part of
    the view (None: the lens's whole image; it may reach beyond the image, the lens model
    holds there too). ``extra_blur_px`` adds a Gaussian blur of that sigma to the lens's
    own (a board out of focus or moving), as the root sum of squares.
    """
    left, top, width, height = window or (0, 0, cam.lens.width, cam.lens.height)
    grey = np.full((height, width), board.background)
    px0, py0, px1, py1 = _paper_window(cam, board, pose)
    if window is not None and (px0, py0, px1, py1) == (0, 0, cam.lens.width, cam.lens.height):
        px0, py0, px1, py1 = left, top, left + width, top + height
    x0, y0 = max(px0, left), max(py0, top)
    x1, y1 = min(px1, left + width), min(py1, top + height)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return grey
    ys, xs = np.mgrid[y0:y1, x0:x1].astype(np.float64)
    u, v = _board_coordinates(cam, board, pose, xs, ys)
    sigma = np.sqrt(cam.blur_px(xs, ys) ** 2 + extra_blur_px**2)
    grey[y0 - top : y1 - top, x0 - left : x1 - left] = board_radiance(
        board, u, v, _jacobian(u, v), sigma, samples=samples
    )
    return grey


def render_view(
    rig: CalibRig, board: PrintedBoard, pose: BoardPose, *, seed: int | None, samples: int = 4
) -> list[NDArray[np.uint16]]:
    """Each camera's raw image of the board (Bayer mosaic or mono; noise when ``seed``)."""
    rng = None if seed is None else np.random.default_rng(seed)
    out = []
    for cam in rig.cameras:
        grey = render_grey(cam, board, pose, samples=samples)
        raw = mosaic(grey[..., None] * np.array(board.colour), rig.bayer)
        out.append(expose(raw, exposure_us=rig.exposure_us, model=rig.sensor, rng=rng))
    return out


def _tilted(tilt_x: float, tilt_y: float, roll: float) -> FloatArray:
    rx = rotation_matrix(np.array([tilt_x, 0.0, 0.0]))
    ry = rotation_matrix(np.array([0.0, tilt_y, 0.0]))
    rz = rotation_matrix(np.array([0.0, 0.0, roll]))
    out: FloatArray = rx @ ry @ rz
    return out


def whole_board_seen(
    rig: CalibRig, board: PrintedBoard, pose: BoardPose, *, margin_px: float = 0.0
) -> list[bool]:
    """Per camera: whether it sees the whole paper, ``margin_px`` in from its image's edges."""
    outline = board.outline_mm() @ pose.R.T + pose.t_mm
    w, h = rig.size
    out = []
    for cam in rig.cameras:
        if np.any((outline @ cam.R.T + cam.t_mm)[:, 2] <= 0):
            out.append(False)
            continue
        p = cam.project(outline)
        out.append(
            bool(
                p.min() >= margin_px
                and p[:, 0].max() <= w - 1 - margin_px
                and p[:, 1].max() <= h - 1 - margin_px
            )
        )
    return out


#: The ninths of an image as (column, row): its centre, its corners, its edges.
CENTRE_NINTH = (1, 1)
CORNER_NINTHS = ((0, 0), (2, 2), (2, 0), (0, 2))
EDGE_NINTHS = ((1, 0), (0, 1), (2, 1), (1, 2))
#: Draws after which `board_poses` passes over a ninth no pose reached.
MISSES_PER_AIM = 500
#: Bisection steps that push a corner-aimed pose into the image's corner.
OUTWARD_STEPS = 6


def _ninth(aim: int, cameras: int) -> tuple[int, int]:
    """The ninth of its camera's image that pose number ``aim`` aims at.

    The cameras take turns. Each camera's turns go through its image's centre, then its
    four corners (starting at a different corner for each camera), then its edges.
    """
    camera, turn = aim % cameras, aim // cameras
    start = camera % len(CORNER_NINTHS)
    order = (CENTRE_NINTH, *CORNER_NINTHS[start:], *CORNER_NINTHS[:start], *EDGE_NINTHS)
    return order[turn % len(order)]


def _aimed_pose(
    cam: RigCamera,
    pixel: FloatArray,
    *,
    rot: FloatArray,
    z_mm: float,
    centre_mm: FloatArray,
    warp_mm: tuple[float, float],
) -> BoardPose:
    """The board turned by ``rot``, its centre ``z_mm`` deep on ``cam``'s ray of ``pixel``."""
    ray = cam.lens.rays(pixel[None])[0]
    point = cam.R.T @ (np.array([ray[0] * z_mm, ray[1] * z_mm, z_mm]) - cam.t_mm)
    return BoardPose(rot, point - rot @ centre_mm, warp_mm)


def _in_view(
    rig: CalibRig, board: PrintedBoard, pose: BoardPose, *, index: int, need: int, margin_px: float
) -> bool:
    """Whether camera ``index`` and ``need`` cameras in all see the whole board."""
    seen = whole_board_seen(rig, board, pose, margin_px=margin_px)
    return bool(seen[index] and sum(seen) >= need)


def _outward(
    start: FloatArray,
    outer: FloatArray,
    make: Callable[[FloatArray], BoardPose],
    whole: Callable[[BoardPose], bool],
) -> BoardPose:
    """The pose ``make`` gives nearest ``outer`` on the way from ``start`` that is ``whole``.

    ``make(start)`` must be whole. Bisection in `OUTWARD_STEPS` steps: a board aimed at a
    corner of the image is pushed into that corner as far as it stays whole in view.
    """
    lo, hi = 0.0, 1.0
    for _ in range(OUTWARD_STEPS):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if whole(make(start + mid * (outer - start))) else (lo, mid)
    return make(start + lo * (outer - start))


def board_poses(
    rig: CalibRig,
    board: PrintedBoard,
    count: int,
    *,
    seed: int,
    max_tilt_deg: float = 35.0,
    fill: tuple[float, float] = (0.35, 0.6),
    warp_mm: tuple[float, float] = (0.0, 0.0),
    min_cameras: int | None = None,
) -> list[BoardPose]:
    """``count`` poses whose whole board every camera sees, spread over the cameras' images.

    The board spans ``fill`` of the image width, is tilted about its x and y axes by up to
    ``max_tilt_deg`` (0: all fronto-parallel) and turned by up to 15 degrees in its plane.
    The poses aim at the cameras in turn, and each camera's aims go through the ninths of
    its image (a random point inside the ninth): its centre, its corners, its edges, as
    the capture's hints ask. A corner-aimed board is then pushed into the image's corner
    as far as it stays whole in view: the corners are where a calibration is least
    certain. At least
    ``min_cameras`` cameras (None: all) see the board whole, the one aimed at among them;
    a ninth that no pose reaches in `MISSES_PER_AIM` draws is passed over.
    """
    need = len(rig.cameras) if min_cameras is None else min_cameras
    rng = np.random.default_rng(seed)
    lens = rig.cameras[0].lens
    w, h = rig.size
    p = board.pattern
    centre_b = np.array([(p.cols - 1) * p.square_mm / 2, (p.rows - 1) * p.square_mm / 2, 0.0])
    width_mm = (p.cols + 1 + 2 * board.margin_squares) * p.square_mm
    margin = 0.02 * w
    poses: list[BoardPose] = []
    aim, misses = 0, 0
    for _ in range(MISSES_PER_AIM * (count + 9)):  # room for each ninth to be passed over once
        if len(poses) == count:
            break
        tilt = np.radians(max_tilt_deg) * rng.uniform(-1, 1, 2)
        roll = np.radians(15.0) * rng.uniform(-1, 1) * (max_tilt_deg > 0)
        rot = _tilted(tilt[0], tilt[1], roll)
        z = lens.fx * width_mm / (rng.uniform(*fill) * w)
        index, (col, row) = aim % len(rig.cameras), _ninth(aim, len(rig.cameras))
        cam = rig.cameras[index]
        target = (0.05 + 0.3 * (np.array([col, row]) + rng.uniform(0, 1, 2))) * np.array([w, h])
        make = partial(_aimed_pose, cam, rot=rot, z_mm=z, centre_mm=centre_b, warp_mm=warp_mm)
        whole = partial(_in_view, rig, board, index=index, need=need, margin_px=margin)
        found = whole(make(target))
        if found and (col, row) in CORNER_NINTHS:  # pushed into the image's corner
            poses.append(_outward(target, np.array([col, row]) / 2 * [w - 1, h - 1], make, whole))
        elif found:
            poses.append(make(target))
        misses = 0 if found else misses + 1
        if found or misses == MISSES_PER_AIM:
            aim, misses = aim + 1, 0
    if len(poses) < count:
        raise ValueError(
            f"found {len(poses)} of {count} board poses that {need} cameras see whole; "
            "allowed: a smaller board, a smaller baseline or a smaller fill"
        )
    return poses


def write_views(
    root: str | Path, rig: CalibRig, board: PrintedBoard, poses: list[BoardPose], *, seed: int
) -> list[Path]:
    """Render and write a views directory (docs/calibration.md); return the views' paths.

    One camera: ``viewNNN.tif`` with the Bayer pattern in its metadata. Four: a quad
    directory ``viewNNN/`` per view (quad.json, cam0..3.tif).
    """
    out = Path(root)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for k, pose in enumerate(poses):
        images = render_view(rig, board, pose, seed=seed + k)
        if len(images) == 1:
            path = out / f"view{k:03d}.tif"
            tifffile.imwrite(path, images[0], metadata={"bayer": rig.bayer})
        elif len(images) == 4:
            manifest = quad_format.QuadManifest(
                cameras=quad_format.quad_cameras(QUAD_POSITIONS),
                bayer=rig.bayer,
                full_scale_dn=(1 << rig.sensor.bits) - 1,
            )
            path = quad_format.write_quad_dir(out / f"view{k:03d}", manifest, images)
        else:
            raise ValueError(
                f"a rig of {len(images)} cameras; allowed: 1 or 4 for a views directory"
            )
        paths.append(path)
    return paths


def truth_json(rig: CalibRig, board: PrintedBoard, poses: list[BoardPose]) -> dict[str, object]:
    """The truth of a views directory: per camera its lens, residual, blur, pose; the boards."""
    return {
        "pattern": board.pattern.spec,
        "cameras": [
            {
                **cam.lens.to_json(),
                "R": cam.R.tolist(),
                "t_mm": cam.t_mm.tolist(),
                "residual_terms": [list(t) for t in cam.residual.terms],
                "blur_px": [cam.blur_centre_px, cam.blur_edge_px],
            }
            for cam in rig.cameras
        ],
        "boards": [
            {"R": p.R.tolist(), "t_mm": p.t_mm.tolist(), "warp_mm": list(p.warp_mm)} for p in poses
        ],
    }
