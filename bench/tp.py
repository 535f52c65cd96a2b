"""Tile processor benchmark: accuracy and speed on a simulated 2592x1936 Bayer quad vs OpenCV.

Renders the simulator's standard quad scene (planes at disparities 0, 0.37, 2.5 and 5.2 px,
a slanted plane, a texture-less plane; GRBG; shot and read noise of a 12-bit sensor), runs
the tile processor (all tiles, 6 pairs, one refinement pass), and in the same run
cv2.StereoSGBM over the four horizontal and vertical pairs and per-tile cv2.phaseCorrelate
on the same 16x16 tiles. Also in the same run: where the tile processor's time goes (per
stage, summed over its threads), the matrix-product arithmetic it does against a batched
float32 matrix product of the same shapes on the same threads (the machine's peak for
it), a quad of twice the width and height (as super-resolved quads are), and the
calibrated case (`calibrated_case`: raw images of a quad whose cameras have their own
distortion and rotation, with the calibration `elphel calibrate solve` finds). Timed runs
take turns (TP, SGBM, TP, ...; large quad, small quad, ...), best of each, so that a drift
in how fast the host runs the vCPUs does not favour one side. Prints exactly one JSON
object; nothing is hard-coded.

    .venv/bin/python bench/tp.py [--width 2592 --height 1936 --seed 0 --threads 2]
                                 [--skip-large] [--skip-phase-correlate]
                                 [--calib-width 640 --calib-height 480 --calib-views 20]
                                 [--skip-calibrated]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import sys
import tempfile
import time
import tracemalloc
import warnings
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from elphel_host.calibrate.pattern import Checkerboard
from elphel_host.calibrate.result import write_calibration
from elphel_host.calibrate.solve import calibrate
from elphel_host.calibrate.views import read_views
from elphel_host.depth.products import dsi_depth
from elphel_host.parallel import parallel_map, single_threaded_blas
from elphel_host.tp import io, processor, tile_pass
from elphel_host.tp.calibrated import CalibratedGeometry, read_calibration
from elphel_host.tp.config import TpConfig
from elphel_host.tp.geometry import QuadGeometry, tile_centres
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

ORTHO_PAIRS = ((0, 1), (2, 3), (0, 2), (1, 3))  # top, bottom (horizontal); left, right (vertical)


def rms(err: np.ndarray) -> float:
    err = err[np.isfinite(err)]
    return float(np.sqrt(np.mean(err**2))) if err.size else float("nan")


def gray_images(raw: np.ndarray, bayer: str | None) -> list[np.ndarray]:
    """8-bit grey images for the OpenCV peers (demosaiced when Bayer)."""
    out = []
    for img in raw:
        img8 = np.clip(img.astype(np.float32) / 4095.0 * 255.0, 0, 255).astype(np.uint8)
        # OpenCV names Bayer codes after the second row: GRBG data is "BayerGB"
        out.append(cv2.cvtColor(img8, cv2.COLOR_BayerGB2GRAY) if bayer else img8)
    return out


def run_sgbm(
    gray: list[np.ndarray], positions: tuple[tuple[float, float], ...]
) -> tuple[list[np.ndarray], float]:
    """Disparity maps (float px, NaN invalid) of the 4 ortho pairs, each in its first
    camera, and the seconds the four took."""
    sgbm = cv2.StereoSGBM_create(
        minDisparity=-2,
        numDisparities=16,
        blockSize=5,
        P1=8 * 25,
        P2=32 * 25,
        uniquenessRatio=5,
        mode=cv2.STEREO_SGBM_MODE_SGBM,
    )
    maps = []
    t0 = time.perf_counter()
    for a, b in ORTHO_PAIRS:
        vertical = positions[a][0] == positions[b][0]
        left, right = gray[a], gray[b]
        if vertical:  # transpose so the baseline is horizontal, first camera on the left
            left, right = cv2.transpose(left), cv2.transpose(right)
        d = sgbm.compute(left, right)
        if vertical:
            d = cv2.transpose(d)
        maps.append(d)
    seconds = time.perf_counter() - t0
    out = []
    for d in maps:
        f = d.astype(np.float32) / 16.0
        f[d <= (-2 - 1) * 16] = np.nan
        out.append(f)
    return out, seconds


def sample_at_tiles(
    maps: list[np.ndarray], truth: np.ndarray, positions: tuple[tuple[float, float], ...]
) -> np.ndarray:
    """Per pair, the map sampled where its first camera sees each tile centre: (4, ty, tx)."""
    ty, tx = truth.shape
    cy = 8.0 * np.arange(ty)[:, None] + 4.0
    cx = 8.0 * np.arange(tx)[None, :] + 4.0
    out = []
    for (a, _), m in zip(ORTHO_PAIRS, maps, strict=True):
        px, py = positions[a]
        x = cx - truth * px  # where camera a sees the tile centre
        y = cy - truth * py
        xi = np.clip(np.round(x - 0.5).astype(int), 0, m.shape[1] - 1)
        yi = np.clip(np.round(y - 0.5).astype(int), 0, m.shape[0] - 1)
        out.append(m[yi, xi])
    return np.stack(out)


def run_phase_correlate(gray: list[np.ndarray], tiles: tuple[int, int]) -> tuple[np.ndarray, float]:
    """Per tile and ortho pair: cv2.phaseCorrelate of the 16x16 tiles at disparity 0 (4, ty, tx)."""
    ty, tx = tiles
    window = cv2.createHanningWindow((16, 16), cv2.CV_64F)
    padded = [np.pad(g.astype(np.float64), 4, mode="edge") for g in gray]
    out = np.full((4, ty, tx), np.nan)
    t0 = time.perf_counter()
    for p, (a, b) in enumerate(ORTHO_PAIRS):
        vertical = p >= 2
        ga, gb = padded[a], padded[b]
        for y in range(ty):
            for x in range(tx):
                ta = ga[8 * y : 8 * y + 16, 8 * x : 8 * x + 16]
                tb = gb[8 * y : 8 * y + 16, 8 * x : 8 * x + 16]
                # without removing the mean, the window's own spectrum pins the peak at 0
                (dx, dy), _ = cv2.phaseCorrelate(ta - ta.mean(), tb - tb.mean(), window)
                # content of the second camera moves by -D along the baseline
                out[p, y, x] = -(dy if vertical else dx)
    return out, time.perf_counter() - t0


def region_rms(est: np.ndarray, truth: simquad.TileTruth, names: list[str]) -> dict[str, float]:
    err = est - truth.disparity
    res = {}
    for name in names:
        m = (truth.label == truth.names.index(name)) & truth.interior
        res[name] = rms(err[m])
    return res


def pass_flops(prep: tile_pass.PreparedQuad, tiles: int) -> dict[str, float]:
    """Floating-point operations of the matrix products of one pass over ``tiles`` tiles."""
    tr = prep.transform
    per_camera = sum(2 * m.shape[0] * m.shape[1] for _, m in tr.blocks)
    window = 2 * tr.windows.shape[0] * tr.windows.shape[1]  # the window's 4-term product
    profiles = sum(2 * b.shape[0] * b.shape[1] for b in prep.profiles.basis)
    return {
        "to_clt": float(tiles * 4 * (per_camera + window)),
        "correlation": float(tiles * profiles),
    }


def matmul_peak(prep: tile_pass.PreparedQuad, threads: int, seconds: float = 1.0) -> float:
    """GFLOP/s of batched float32 products of the transform's shapes on ``threads`` threads."""
    rng = np.random.default_rng(0)
    mats = [m for _, m in prep.transform.blocks]
    chunk = TpConfig().chunk_tiles
    data = [rng.random((chunk, m.shape[0]), dtype=np.float32) for m in mats]
    flops_one = sum(2 * chunk * m.shape[0] * m.shape[1] for m in mats)

    def work(_: int) -> int:
        n = 0
        t_end = time.perf_counter() + seconds
        while time.perf_counter() < t_end:
            for a, m in zip(data, mats, strict=True):
                a @ m
            n += 1
        return n

    best = 0.0
    with single_threaded_blas():
        for _ in range(3):
            t0 = time.perf_counter()
            counts = parallel_map(work, list(range(threads)), threads=threads)
            dt = time.perf_counter() - t0
            best = max(best, sum(counts) * flops_one / dt / 1e9)
    return best


def traced_tp(quad: QuadImages, config: TpConfig) -> tuple[dict[str, np.ndarray], int]:
    """DSI and peak traced memory of one run under tracemalloc (slower: not timed)."""
    tracemalloc.start()
    try:
        dsi = processor.disparity_map(quad, config=config)
        return dsi, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def timed_tp(quad: QuadImages, config: TpConfig) -> tuple[float, dict[str, float]]:
    """Seconds of one DSI and its stage times (summed over threads)."""
    with tile_pass.stage_times() as st:
        t = time.perf_counter()
        processor.disparity_map(quad, config=config)
        return time.perf_counter() - t, dict(st)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=2592)
    ap.add_argument("--height", type=int, default=1936)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument(
        "--repeat",
        type=int,
        default=3,
        help="timing runs of each side, taking turns (best reported)",
    )
    ap.add_argument("--skip-phase-correlate", action="store_true")
    ap.add_argument(
        "--skip-large", action="store_true", help="skip the quad of twice the width and height"
    )
    add_calibrated_options(ap)
    args = ap.parse_args()

    rig = simquad.QuadRig(width=args.width, height=args.height)
    t0 = time.perf_counter()
    scene = simquad.standard_scene(rig, seed=args.seed)
    raw = simquad.render_quad(scene, seed=args.seed)
    truth = simquad.tile_truth(scene)
    render_s = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        simquad.write_quad_dir(tmp, raw, rig)
        qs = io.read_quad_dir(tmp)
    quad = qs.quad
    config = TpConfig(threads=args.threads, refine_passes=1)

    load_before = os.getloadavg()[0]
    # the first run is traced (tracemalloc); then the TP and SGBM take turns, so that
    # both see about the same machine (how fast the host runs the vCPUs drifts)
    gray = gray_images(raw, rig.bayer)
    dsi, peak = traced_tp(quad, config)
    times: list[float] = []
    sgbm_times: list[float] = []
    stages: dict[str, float] = {}
    for _ in range(args.repeat):
        dt, st = timed_tp(quad, config)
        if not times or dt < min(times):
            stages = st
        times.append(dt)
        maps, t_sgbm = run_sgbm(gray, rig.positions)
        sgbm_times.append(t_sgbm)
    tp_s = min(times)
    reach = max(abs(s) for s in config.scan) + config.radius * (config.refine_passes + 1)
    prep = tile_pass.prepare(quad, config, reach)
    ty, tx = dsi["disparity"].shape
    flops = pass_flops(prep, ty * tx)
    passes = len(config.scan) + config.refine_passes
    # the first pass measures only every first_pass_step-th tile along each axis
    step = config.first_pass_step if config.refine_passes else 1
    first_tiles = -(-ty // step) * -(-tx // step)
    tiles_measured = len(config.scan) * first_tiles + config.refine_passes * ty * tx
    total_flops = tiles_measured / (ty * tx) * sum(flops.values())
    peak_gflops = matmul_peak(prep, args.threads)
    del prep

    fronto = [n for n in truth.names if n.startswith("fronto_")]
    regions = [*fronto, "slanted"]
    tp_rms = region_rms(dsi["disparity"], truth, regions)
    fronto_mask = np.isin(truth.label, [truth.names.index(n) for n in fronto]) & truth.interior
    tp_fronto = rms((dsi["disparity"] - truth.disparity)[fronto_mask])

    textured = truth.textured & truth.interior
    flat = (truth.label == truth.names.index("flat")) & truth.interior
    s_tex, s_flat = dsi["strength"][textured], dsi["strength"][flat]
    threshold = float(np.sqrt(np.median(s_tex) * np.median(s_flat)))
    separation = {
        "median_textured": float(np.median(s_tex)),
        "median_textureless": float(np.median(s_flat)),
        "threshold_geometric_mean": threshold,
        "textured_above": float(np.mean(s_tex > threshold)),
        "textureless_below": float(np.mean(s_flat < threshold)),
    }

    sgbm_s = min(sgbm_times)
    sg = sample_at_tiles(maps, truth.disparity, rig.positions)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # tiles where no pair is valid -> NaN
        sg_mean = np.nanmean(sg, axis=0)
    sgbm_rms = region_rms(sg_mean, truth, regions)
    sgbm_fronto = rms((sg_mean - truth.disparity)[fronto_mask])
    sgbm_valid = float(np.mean(np.isfinite(sg_mean[fronto_mask])))

    result: dict[str, Any] = {
        "conditions": {
            "cpus": os.cpu_count(),
            "load_average_1min_before_tp": load_before,
            "load_average_1min_after": os.getloadavg()[0],
            "python": sys.version.split()[0],
            "numpy": np.__version__,
            "opencv": cv2.__version__,
            "machine": platform.machine(),
            "threads": args.threads,
            "tp_runs_s": [round(t, 3) for t in times],
        },
        "image": {
            "width": args.width,
            "height": args.height,
            "bayer": rig.bayer,
            "tiles": int(dsi["disparity"].size),
            "render_s": round(render_s, 1),
        },
        "tile_processor": {
            "seconds": round(tp_s, 3),
            "peak_traced_memory_mb": round(peak / 2**20, 1),
            "max_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
            "rms_px": {k: round(v, 4) for k, v in tp_rms.items()},
            "rms_fronto_all_px": round(tp_fronto, 4),
            "strength": {k: round(v, 4) for k, v in separation.items()},
            "stage_seconds_summed_over_threads": {k: round(v, 3) for k, v in stages.items()},
            "stage_fraction": {
                k: round(v / max(sum(stages.values()), 1e-12), 3) for k, v in stages.items()
            },
            "passes": passes,
            "tiles_measured_over_all_passes": tiles_measured,
            "matmul_gflop": round(total_flops / 1e9, 2),
            "matmul_gflop_per_pass": {k: round(v / 1e9, 2) for k, v in flops.items()},
            "achieved_gflops": round(total_flops / tp_s / 1e9, 1),
        },
        "matmul_peak": {
            "what": "batched float32 products of the transform's shapes, same threads",
            "gflops": round(peak_gflops, 1),
        },
        "sgbm": {
            "seconds_4_pairs": round(sgbm_s, 3),
            "runs_s": [round(t, 3) for t in sgbm_times],
            "rms_px": {k: round(v, 4) for k, v in sgbm_rms.items()},
            "rms_fronto_all_px": round(sgbm_fronto, 4),
            "valid_fraction_fronto": round(sgbm_valid, 4),
        },
    }
    ratios: dict[str, float] = {
        "sgbm_time_over_tp_time": round(sgbm_s / tp_s, 3),
        "sgbm_rms_over_tp_rms": round(sgbm_fronto / tp_fronto, 3),
        "tp_achieved_over_matmul_peak": round(total_flops / tp_s / 1e9 / peak_gflops, 3),
    }
    if not args.skip_large:
        big_rig = simquad.QuadRig(width=2 * args.width, height=2 * args.height)
        big_scene = simquad.standard_scene(big_rig, seed=args.seed)
        big_raw = simquad.render_quad(big_scene, seed=args.seed)
        with tempfile.TemporaryDirectory() as tmp:
            simquad.write_quad_dir(tmp, big_raw, big_rig)
            big_quad = io.read_quad_dir(tmp).quad
        del big_raw
        # the first run is traced (peak memory); then the large and the small quad take
        # turns, best of --repeat each, so that both times see about the same load
        _, big_peak = traced_tp(big_quad, config)
        big_times: list[float] = []
        again: list[float] = []
        big_stages: dict[str, float] = {}
        for _ in range(args.repeat):
            dt, st = timed_tp(big_quad, config)
            if not big_times or dt < min(big_times):
                big_stages = st
            big_times.append(dt)
            again.append(timed_tp(quad, config)[0])
        big_s, small_s = min(big_times), min(again)
        result["large_quad"] = {
            "width": 2 * args.width,
            "height": 2 * args.height,
            "seconds": round(big_s, 3),
            "runs_s": [round(t, 3) for t in big_times],
            "small_quad_taking_turns_runs_s": [round(t, 3) for t in again],
            "peak_traced_memory_mb": round(big_peak / 2**20, 1),
            "stage_seconds_summed_over_threads": {k: round(v, 3) for k, v in big_stages.items()},
        }
        ratios["large_time_over_small_time"] = round(big_s / small_s, 3)
        result["large_quad"]["max_rss_mb_process"] = round(
            resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1
        )
    if not args.skip_phase_correlate:
        pc, pc_s = run_phase_correlate(gray, quad.tiles)
        pc_mean = np.nanmean(pc, axis=0)
        pc_fronto = rms((pc_mean - truth.disparity)[fronto_mask])
        result["phase_correlate"] = {
            "seconds_4_pairs": round(pc_s, 3),
            "rms_px": {k: round(v, 4) for k, v in region_rms(pc_mean, truth, regions).items()},
            "rms_fronto_all_px": round(pc_fronto, 4),
        }
        ratios["phase_correlate_time_over_tp_time"] = round(pc_s / tp_s, 3)
        ratios["phase_correlate_rms_over_tp_rms"] = round(pc_fronto / tp_fronto, 3)
    result["ratios"] = ratios
    targets = {
        "3x_faster_than_sgbm": sgbm_s >= 3 * tp_s,
        "fronto_all_rms_le_0.03": tp_fronto <= 0.03,
        "slanted_rms_le_0.045": tp_rms["slanted"] <= 0.045,
        "peak_memory_le_1gb": peak <= 2**30,
        "fronto_rms_le_0.05": all(tp_rms[n] <= 0.05 for n in fronto),
        "slanted_rms_le_0.1": tp_rms["slanted"] <= 0.1,
        "time_le_2s": tp_s <= 2.0,
        "peak_memory_le_2gb": peak <= 2 * 2**30,
        "as_fast_as_sgbm": sgbm_s >= tp_s,
        "3x_more_accurate_than_sgbm": sgbm_fronto >= 3 * tp_fronto,
    }
    if "large_quad" in result:
        targets["large_time_le_4.5x"] = ratios["large_time_over_small_time"] <= 4.5
        targets["large_peak_memory_le_3gb"] = big_peak <= 3 * 2**30
    if "phase_correlate" in result:
        targets["faster_than_phase_correlate"] = ratios["phase_correlate_time_over_tp_time"] > 1
        targets["more_accurate_than_phase_correlate"] = (
            ratios["phase_correlate_rms_over_tp_rms"] > 1
        )
    if not args.skip_calibrated:
        result["calibrated"] = calibrated_case(args, quad, config)
        targets.update(result["calibrated"].pop("targets_met"))
    result["targets_met"] = targets
    print(json.dumps(result, sort_keys=True))
    return 0


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
    rig = make_rig(args.calib_width, args.calib_height, seed=args.seed)
    cal_path, solve_s = solved_calibration(rig, args.calib_views, args.seed, out)
    ideal = rectified_rig(rig)
    scene = simquad.standard_scene(ideal, seed=args.seed)
    raw = render_raw_quad(scene, rig, seed=args.seed + 7)
    dirs = {
        "calibrated": write_raw_quad_dir(out / "raw", raw, rig, calibration=cal_path),
        "uncalibrated": write_raw_quad_dir(out / "plain", raw, rig),
        "rectified": simquad.write_quad_dir(
            out / "rect", simquad.render_quad(scene, seed=args.seed + 7), ideal
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


def geometry_cost(args: argparse.Namespace, quad: QuadImages, config: TpConfig) -> dict[str, Any]:
    """The full-size quad's DSI time with a calibrated geometry against the ideal one.

    The calibration is the true one of a rig of the full size (the images are the ideal
    quad's, so only the time means something). Also the geometry's own work: placing
    every camera's tiles once per pass and the per-tile gain.
    """
    with tempfile.TemporaryDirectory() as tmp:
        rig = make_rig(quad.images.shape[2], quad.images.shape[1], seed=args.seed)
        cal = read_calibration(write_true_calibration(tmp, rig))
    geometry = QuadGeometry(positions=quad.geometry.positions, calibration=cal)
    calibrated = QuadImages(quad.images, bayer=quad.bayer, geometry=geometry)
    plain_times, cal_times = [], []
    for _ in range(args.repeat):
        plain_times.append(timed_tp(quad, config)[0])
        cal_times.append(timed_tp(calibrated, config)[0])
    cy, cx = (c.ravel() for c in tile_centres(*quad.tiles))
    passes = len(config.scan) + config.refine_passes
    t0 = time.perf_counter()
    geometry.disparity_gain(cx, cy)
    for _ in range(passes):
        for cam in range(4):
            geometry.place_camera(cam, cx, cy, np.zeros(cx.size))
    own_s = time.perf_counter() - t0
    tp_s, tp_cal_s = min(plain_times), min(cal_times)
    return {
        "tp_s": round(tp_s, 3),
        "tp_calibrated_s": round(tp_cal_s, 3),
        "calibrated_time_over_ideal_time": round(tp_cal_s / tp_s, 3),
        "geometry_s": round(own_s, 4),
        "geometry_share_of_tp": round(own_s / tp_s, 4),
    }


def calibrated_case(args: argparse.Namespace, quad: QuadImages, config: TpConfig) -> dict[str, Any]:
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
    cost = geometry_cost(args, quad, config)
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


if __name__ == "__main__":
    sys.exit(main())
