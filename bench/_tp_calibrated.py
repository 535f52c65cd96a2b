"""bench/tp.py's calibrated case: raw images of a quad whose cameras have their own distortion
and rotation, with the calibration `elphel calibrate solve` finds, against the same scene
rendered already rectified (and the raw images read as ideal), plus the cost of the
calibrated geometry on the full-size quad.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from elphel_host.calibrate.camera_model import CameraModel
from elphel_host.calibrate.pattern import Checkerboard
from elphel_host.calibrate.result import write_calibration
from elphel_host.calibrate.solve import calibrate
from elphel_host.calibrate.views import read_views
from elphel_host.depth.products import dsi_depth
from elphel_host.tp import io, processor
from elphel_host.tp.calibrated import CalibratedGeometry, read_calibration
from elphel_host.tp.config import TpConfig
from elphel_host.tp.geometry import IDEAL_POSITIONS, QuadGeometry, tile_centres
from elphel_host.tp.images import QuadImages
from elphel_sim import quad as simquad
from elphel_sim.calib_rig import board_poses, make_rig, write_views
from elphel_sim.calib_scene import (
    rectified_rig,
    render_raw_quad,
    write_raw_quad_dir,
    write_true_calibration,
)
from elphel_sim.calib_target import PrintedBoard

TimedTp = Callable[[QuadImages, TpConfig], tuple[float, dict[str, float]]]


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def add_calibrated_options(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--calib-width", type=int, default=640, help="calibrated case's image width")
    ap.add_argument("--calib-height", type=int, default=480)
    ap.add_argument("--calib-views", type=int, default=20, help="board views for its solve")
    ap.add_argument("--skip-calibrated", action="store_true", help="skip the calibrated case")


def solved_calibration(rig: Any, views: int, seed: int, out: Path) -> tuple[Path, float]:
    """Render board views of ``rig``, solve them as `elphel calibrate solve` does; the file."""
    board = PrintedBoard(Checkerboard(9, 6, 25.0))
    poses = board_poses(rig, board, views, seed=seed + 1, min_cameras=2)
    write_views(out / "views", rig, board, poses, seed=seed + 100)
    t0 = time.perf_counter()
    cal = calibrate(read_views(out / "views", board.pattern), cross_validate=False)
    seconds = time.perf_counter() - t0
    return write_calibration(cal, out / "calib"), seconds


def calibrated_dirs(args: argparse.Namespace, out: Path) -> tuple[dict[str, Path], Any, float]:
    """Quad directories of one scene: raw + solved calibration, raw alone, rectified."""
    rig = make_rig(args.calib_width, args.calib_height, seed=args.seeds[0])
    cal_path, solve_s = solved_calibration(rig, args.calib_views, args.seeds[0], out)
    ideal = rectified_rig(rig)
    scene = simquad.standard_scene(ideal, seed=args.seeds[0])
    raw = render_raw_quad(scene, rig, seed=args.seeds[0] + 7)
    dirs = {
        "calibrated": write_raw_quad_dir(out / "raw", raw, rig, calibration=cal_path),
        "uncalibrated": write_raw_quad_dir(out / "plain", raw, rig),
        "rectified": simquad.write_quad_dir(
            out / "rect", simquad.render_quad(scene, seed=args.seeds[0] + 7), ideal
        ),
    }
    return dirs, simquad.tile_truth(scene), solve_s


def plane_depth_errors(qs: io.QuadSet, dsi: dict[str, np.ndarray], truth: Any) -> dict[str, float]:
    """Per fronto-parallel plane, the median depth of its points against its true depth."""
    cal = qs.quad.geometry.calibration
    assert isinstance(cal, CalibratedGeometry)
    depth = dsi_depth(dsi, qs.quad, cal.depth_optics()).depth_mm
    out = {}
    for name in truth.names:
        d = float(name.split("_")[1]) if name.startswith("fronto_") else 0.0
        mask = (truth.label == truth.names.index(name)) & truth.interior
        if d > 0 and mask.any():
            true_mm = cal.focal_px * cal.baseline_mm / d
            out[name] = round(100 * (float(np.nanmedian(depth[mask])) / true_mm - 1), 4)
    return out


def ideal_calibration(width: int, height: int, focal_px: float) -> CalibratedGeometry:
    """Pinhole cameras on the ideal square: tiles placed as by the ideal geometry."""
    cameras = []
    for px, py in IDEAL_POSITIONS:
        lens = CameraModel(width, height, focal_px, focal_px, (width - 1) / 2, (height - 1) / 2)
        centre_mm = 100.0 * np.array([px + 0.5, py + 0.5, 0.0])  # in camera 0's frame
        cameras.append((lens, np.eye(3), -centre_mm))
    return CalibratedGeometry.from_cameras(cameras)


def geometry_cost(
    args: argparse.Namespace, quad: QuadImages, config: TpConfig, timed_tp: TimedTp
) -> dict[str, Any]:
    """The full-size quad's DSI time with a calibrated geometry against the ideal one.

    Two calibrations, timed taking turns with the ideal geometry: the true one of a rig
    of the full size (the images are the ideal quad's, so only the time means something,
    and the passes' targets differ from the ideal run's: this is the target's figure),
    and pinhole cameras on the ideal square (the same tiles, targets and work as the
    ideal run: the difference is the geometry's own cost); wall and CPU seconds (best of
    ``--repeat`` each; CPU seconds move less on a loaded machine). Also the geometry's own
    work timed alone: placing every camera's tiles once per pass and the per-tile gain.
    """
    w, h = quad.images.shape[2], quad.images.shape[1]
    with tempfile.TemporaryDirectory() as tmp:
        cal = read_calibration(write_true_calibration(tmp, make_rig(w, h, seed=args.seeds[0])))
    geometry = QuadGeometry(positions=quad.geometry.positions, calibration=cal)
    calibrated = QuadImages(quad.images, bayer=quad.bayer, geometry=geometry)
    pinhole = QuadGeometry(calibration=ideal_calibration(w, h, cal.focal_px))
    square = QuadImages(quad.images, bayer=quad.bayer, geometry=pinhole)
    times: dict[str, list[float]] = {"ideal": [], "calibrated": [], "pinhole": []}
    cpu: dict[str, list[float]] = {name: [] for name in times}
    for _ in range(args.repeat):
        for name, q in (("ideal", quad), ("calibrated", calibrated), ("pinhole", square)):
            c0 = time.process_time()
            times[name].append(timed_tp(q, config)[0])
            cpu[name].append(time.process_time() - c0)
    cy, cx = (c.ravel() for c in tile_centres(*quad.tiles))
    passes = len(config.scan) + config.refine_passes
    t0 = time.perf_counter()
    geometry.disparity_gain(cx, cy)
    for _ in range(passes):
        for cam in range(4):
            geometry.place_camera(cam, cx, cy, np.zeros(cx.size))
    own_s = time.perf_counter() - t0
    best = {k: min(v) for k, v in times.items()}
    best_cpu = {k: min(v) for k, v in cpu.items()}
    return {
        "cpu_s": {k: round(v, 3) for k, v in best_cpu.items()},
        "calibrated_cpu_over_ideal_cpu": round(best_cpu["calibrated"] / best_cpu["ideal"], 3),
        "pinhole_calibration_cpu_over_ideal_cpu": round(best_cpu["pinhole"] / best_cpu["ideal"], 3),
        "tp_s": round(best["ideal"], 3),
        "tp_calibrated_s": round(best["calibrated"], 3),
        "calibrated_time_over_ideal_time": round(best["calibrated"] / best["ideal"], 3),
        "tp_pinhole_calibration_s": round(best["pinhole"], 3),
        "pinhole_calibration_time_over_ideal_time": round(best["pinhole"] / best["ideal"], 3),
        "geometry_s": round(own_s, 4),
        "geometry_share_of_tp": round(own_s / best["ideal"], 4),
    }


def calibrated_case(
    args: argparse.Namespace, quad: QuadImages, config: TpConfig, timed_tp: TimedTp
) -> dict[str, Any]:
    """Raw images with their solved calibration against the same scene rendered rectified.

    The rig (`elphel_sim.calib_rig.make_rig`): four cameras with their own lens (rational
    model, coefficients within 10 %), focal length (1 %), principal point (1 % of the
    width) and a rotation of about 0.4 degrees; calibrated by the solve of
    ``--calib-views`` rendered board views. The scene is the standard one seen by the
    rig made ideal (`elphel_sim.calib_scene.rectified_rig`), whose tile truth is both
    DSIs' truth. Peers in the same run: the rectified quad (ideal geometry) and the raw
    quad read as an ideal one.
    """
    with tempfile.TemporaryDirectory() as tmp:
        dirs, truth, solve_s = calibrated_dirs(args, Path(tmp))
        sets = {name: io.read_quad_dir(d) for name, d in dirs.items()}
    scored = truth.interior & truth.textured
    errors, dsis = {}, {}
    for name, qs in sets.items():
        dsis[name] = processor.disparity_map(qs.quad, config=config)
        errors[name] = rms((dsis[name]["disparity"] - truth.disparity)[scored])
    depth = plane_depth_errors(sets["calibrated"], dsis["calibrated"], truth)
    cost = geometry_cost(args, quad, config, timed_tp)
    ratio = errors["calibrated"] / errors["rectified"]
    return {
        "image": {"width": args.calib_width, "height": args.calib_height},
        "views": args.calib_views,
        "detect_and_solve_s": round(solve_s, 1),
        "scored_tiles": int(scored.sum()),
        "rms_px": {k: round(v, 4) for k, v in errors.items()},
        "calibrated_rms_over_rectified_rms": round(ratio, 3),
        "plane_depth_error_pct": depth,
        "cost": cost,
        "targets_met": {
            "calibrated_rms_le_1.2x_rectified": ratio <= 1.2,
            "calibrated_plane_depth_within_0.5pct": all(abs(v) <= 0.5 for v in depth.values()),
            "calibrated_geometry_le_10pct_of_tp": cost["calibrated_time_over_ideal_time"] <= 1.1,
        },
    }
