"""Tile processor benchmark: speed and accuracy on four simulated 2592x1936 Bayer quads vs OpenCV.

Renders the simulator's standard quad scene once per seed (default four seeds: each its own
textures and noise; planes at disparities 0, 0.37, 2.5 and 5.2 px, a slanted plane, a
texture-less plane; GRBG; shot and read noise of a 12-bit sensor), runs the tile processor
on each (all tiles, 6 pairs, one refinement pass) and in the same run cv2.StereoSGBM over
the four horizontal and vertical pairs of the same quad. Timed runs take turns (TP q0,
SGBM q0, TP q1, ...; best of --repeat each), so that a drift in how fast the host runs the
vCPUs does not favour one side. Reported per quad and as the worst over the quads: SGBM's
time over the TP's and the RMS errors. Also: where the TP's time goes (per stage, summed
over its threads, first quad), the arithmetic of its transforms and matrix products
against batched float32 matrix products of the transform's dense shapes on the same
threads (the machine's matmul rate), a quad of twice the width and height (as super-resolved quads
are), and per-tile cv2.phaseCorrelate on the first quad, and the calibrated case
(bench/_tp_calibrated.py: raw images of a quad whose cameras have their own distortion and
rotation, with the calibration `elphel calibrate solve` finds). Prints exactly one JSON
object; nothing is hard-coded.

    .venv/bin/python bench/tp.py [--width 2592 --height 1936 --seeds 0 1 2 3 --threads 2]
                                 [--repeat 3] [--skip-large] [--skip-phase-correlate]
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
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from _tp_calibrated import add_calibrated_options, calibrated_case

from elphel_host.parallel import parallel_map, single_threaded_blas
from elphel_host.tp import io, processor, tile_pass
from elphel_host.tp.config import TpConfig
from elphel_host.tp.images import QuadImages
from elphel_sim import quad as simquad

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
    """Floating-point operations of the transforms and products of one pass over ``tiles``."""
    tr = prep.transform
    planes, inner = tr.plane_rows.size, tr.inner
    # separable transform, as computed: 16 (kh, re/im) lanes along the rows, then per
    # colour plane and kv two 16-lane sums down the columns
    rows = planes * inner * inner * 16
    columns = sum(int(p1 - p0) * int(kvs) * inner * 32 for p0, p1, _, kvs in tr.colours)
    profiles = sum(2 * b.shape[0] * b.shape[1] for b in prep.profiles.basis)
    return {
        "to_clt": float(tiles * 4 * 2 * (rows + columns)),
        "correlation": float(tiles * profiles),
    }


def matmul_peak(prep: tile_pass.PreparedQuad, threads: int, seconds: float = 1.0) -> float:
    """GFLOP/s of batched float32 products on ``threads`` threads (the machine's rate).

    The shapes are those of the transform done as one dense product per colour: a chunk's
    samples of the colour's planes times (samples, 4 frequencies).
    """
    rng = np.random.default_rng(0)
    tr = prep.transform
    mats = [
        rng.random((int(p1 - p0) * tr.inner**2, 4 * int(n)), dtype=np.float32)
        for p0, p1, n, _ in tr.colours
    ]
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


@dataclass
class BenchQuad:
    """One rendered quad of the standard scene: its images, truth and OpenCV grey images."""

    seed: int
    rig: simquad.QuadRig
    quad: QuadImages
    truth: simquad.TileTruth
    gray: list[np.ndarray]
    render_s: float


def render(width: int, height: int, seed: int) -> BenchQuad:
    """The standard scene rendered with ``seed`` (its textures and noise), read back."""
    rig = simquad.QuadRig(width=width, height=height)
    t0 = time.perf_counter()
    scene = simquad.standard_scene(rig, seed=seed)
    raw = simquad.render_quad(scene, seed=seed)
    truth = simquad.tile_truth(scene)
    render_s = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        simquad.write_quad_dir(tmp, raw, rig)
        quad = io.read_quad_dir(tmp).quad
    return BenchQuad(seed, rig, quad, truth, gray_images(raw, rig.bayer), render_s)


def fronto_mask(truth: simquad.TileTruth) -> np.ndarray:
    fronto = [n for n in truth.names if n.startswith("fronto_")]
    return np.isin(truth.label, [truth.names.index(n) for n in fronto]) & truth.interior


def tp_accuracy(dsi: dict[str, np.ndarray], truth: simquad.TileTruth) -> dict[str, Any]:
    """RMS per region and over all fronto-parallel tiles; strength separation."""
    regions = [n for n in truth.names if n.startswith("fronto_")] + ["slanted"]
    rms_px = region_rms(dsi["disparity"], truth, regions)
    fronto = rms((dsi["disparity"] - truth.disparity)[fronto_mask(truth)])
    textured = truth.textured & truth.interior
    flat = (truth.label == truth.names.index("flat")) & truth.interior
    s_tex, s_flat = dsi["strength"][textured], dsi["strength"][flat]
    threshold = float(np.sqrt(np.median(s_tex) * np.median(s_flat)))
    return {
        "rms_px": {k: round(v, 4) for k, v in rms_px.items()},
        "rms_fronto_all_px": round(fronto, 5),
        "strength": {
            "median_textured": round(float(np.median(s_tex)), 4),
            "median_textureless": round(float(np.median(s_flat)), 4),
            "threshold_geometric_mean": round(threshold, 4),
            "textured_above": round(float(np.mean(s_tex > threshold)), 4),
            "textureless_below": round(float(np.mean(s_flat < threshold)), 4),
        },
    }


def sgbm_accuracy(maps: list[np.ndarray], q: BenchQuad) -> dict[str, Any]:
    """SGBM's four maps sampled at the tile centres and averaged, against the truth."""
    sg = sample_at_tiles(maps, q.truth.disparity, q.rig.positions)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # tiles where no pair is valid -> NaN
        sg_mean = np.nanmean(sg, axis=0)
    regions = [n for n in q.truth.names if n.startswith("fronto_")] + ["slanted"]
    mask = fronto_mask(q.truth)
    return {
        "rms_px": {k: round(v, 4) for k, v in region_rms(sg_mean, q.truth, regions).items()},
        "rms_fronto_all_px": round(rms((sg_mean - q.truth.disparity)[mask]), 4),
        "valid_fraction_fronto": round(float(np.mean(np.isfinite(sg_mean[mask]))), 4),
    }


@dataclass
class Turns:
    """Per quad, the wall and CPU seconds of each timed run of the TP and of SGBM."""

    tp: list[list[float]]
    tp_cpu: list[list[float]]
    sgbm: list[list[float]]
    sgbm_cpu: list[list[float]]
    maps: list[list[np.ndarray]]  # SGBM's maps of each quad
    stages: dict[str, float]  # stage times of the fastest TP run of the first quad


def timed_turns(quads: list[BenchQuad], config: TpConfig, repeat: int) -> Turns:
    """TP and SGBM timed in turns over all quads (TP q0, SGBM q0, TP q1, ...), ``repeat`` rounds."""
    n = len(quads)
    turns = Turns(
        tp=[[] for _ in range(n)],
        tp_cpu=[[] for _ in range(n)],
        sgbm=[[] for _ in range(n)],
        sgbm_cpu=[[] for _ in range(n)],
        maps=[[] for _ in range(n)],
        stages={},
    )
    for _ in range(repeat):
        for i, q in enumerate(quads):
            c0 = time.process_time()
            dt, st = timed_tp(q.quad, config)
            turns.tp_cpu[i].append(time.process_time() - c0)
            if i == 0 and (not turns.tp[0] or dt < min(turns.tp[0])):
                turns.stages = st
            turns.tp[i].append(dt)
            c0 = time.process_time()
            turns.maps[i], t_sgbm = run_sgbm(q.gray, q.rig.positions)
            turns.sgbm_cpu[i].append(time.process_time() - c0)
            turns.sgbm[i].append(t_sgbm)
    return turns


def matmul_figures(q: BenchQuad, config: TpConfig, threads: int, tp_s: float) -> dict[str, Any]:
    """The DSI's transform and product arithmetic, its rate, and the machine's matmul rate."""
    reach = max(abs(s) for s in config.scan) + config.radius * (config.refine_passes + 1)
    prep = tile_pass.prepare(q.quad, config, reach)
    ty, tx = q.quad.tiles
    flops = pass_flops(prep, ty * tx)
    # the first pass measures only every first_pass_step-th tile along each axis
    step = config.first_pass_step if config.refine_passes else 1
    first_tiles = -(-ty // step) * -(-tx // step)
    tiles_measured = len(config.scan) * first_tiles + config.refine_passes * ty * tx
    total = tiles_measured / (ty * tx) * sum(flops.values())
    peak = matmul_peak(prep, threads)
    return {
        "passes": len(config.scan) + config.refine_passes,
        "tiles_measured_over_all_passes": tiles_measured,
        "matmul_gflop": round(total / 1e9, 2),
        "matmul_gflop_per_pass": {k: round(v / 1e9, 2) for k, v in flops.items()},
        "achieved_gflops": round(total / tp_s / 1e9, 1),
        "peak_gflops": round(peak, 1),
        "achieved_over_peak": round(total / tp_s / 1e9 / peak, 3),
    }


def large_quad(args: argparse.Namespace, config: TpConfig, small: QuadImages) -> dict[str, Any]:
    """A quad of twice the width and height against the small one, taking turns."""
    big = render(2 * args.width, 2 * args.height, args.seeds[0]).quad
    _, big_peak = traced_tp(big, config)
    big_times: list[float] = []
    again: list[float] = []
    for _ in range(args.repeat):
        big_times.append(timed_tp(big, config)[0])
        again.append(timed_tp(small, config)[0])
    return {
        "width": 2 * args.width,
        "height": 2 * args.height,
        "seconds": round(min(big_times), 3),
        "runs_s": [round(t, 3) for t in big_times],
        "small_quad_taking_turns_runs_s": [round(t, 3) for t in again],
        "peak_traced_memory_mb": round(big_peak / 2**20, 1),
        "large_time_over_small_time": round(min(big_times) / min(again), 3),
    }


def phase_correlate(q: BenchQuad, tp_s: float, tp_fronto: float) -> dict[str, Any]:
    """Per-tile cv2.phaseCorrelate at disparity 0 on the first quad."""
    pc, pc_s = run_phase_correlate(q.gray, q.quad.tiles)
    pc_mean = np.nanmean(pc, axis=0)
    regions = [n for n in q.truth.names if n.startswith("fronto_")] + ["slanted"]
    pc_fronto = rms((pc_mean - q.truth.disparity)[fronto_mask(q.truth)])
    return {
        "seconds_4_pairs": round(pc_s, 3),
        "rms_px": {k: round(v, 4) for k, v in region_rms(pc_mean, q.truth, regions).items()},
        "rms_fronto_all_px": round(pc_fronto, 4),
        "time_over_tp_time": round(pc_s / tp_s, 3),
        "rms_over_tp_rms": round(pc_fronto / tp_fronto, 3),
    }


def per_quad(quads: list[BenchQuad], config: TpConfig, turns: Turns) -> list[dict[str, Any]]:
    """Per quad: times, the ratio SGBM / TP, and both sides' accuracy."""
    out = []
    for i, q in enumerate(quads):
        dsi = processor.disparity_map(q.quad, config=config)
        tp_s, sgbm_s = min(turns.tp[i]), min(turns.sgbm[i])
        tp_cpu, sgbm_cpu = min(turns.tp_cpu[i]), min(turns.sgbm_cpu[i])
        out.append(
            {
                "seed": q.seed,
                "render_s": round(q.render_s, 1),
                "tp_seconds": round(tp_s, 3),
                "tp_runs_s": [round(t, 3) for t in turns.tp[i]],
                "tp_cpu_seconds": round(tp_cpu, 3),
                "sgbm_seconds_4_pairs": round(sgbm_s, 3),
                "sgbm_runs_s": [round(t, 3) for t in turns.sgbm[i]],
                "sgbm_cpu_seconds": round(sgbm_cpu, 3),
                "sgbm_time_over_tp_time": round(sgbm_s / tp_s, 3),
                "sgbm_cpu_over_tp_cpu": round(sgbm_cpu / tp_cpu, 3),
                "tp": tp_accuracy(dsi, q.truth),
                "sgbm": sgbm_accuracy(turns.maps[i], q),
            }
        )
    return out


def targets_met(result: dict[str, Any]) -> dict[str, bool]:
    worst = result["worst_quad"]
    tp = result["tile_processor"]
    targets = {
        "4x_faster_than_sgbm_worst_quad": worst["sgbm_time_over_tp_time"] >= 4.0,
        "fronto_all_rms_le_0.03_every_quad": worst["tp_rms_fronto_all_px"] <= 0.03,
        "slanted_rms_le_0.045_every_quad": worst["tp_rms_slanted_px"] <= 0.045,
        "3x_faster_than_sgbm_worst_quad": worst["sgbm_time_over_tp_time"] >= 3.0,
        "peak_memory_le_1gb": tp["peak_traced_memory_mb"] <= 1024,
        "time_le_2s_every_quad": worst["tp_seconds"] <= 2.0,
        "3x_more_accurate_than_sgbm_every_quad": worst["sgbm_rms_over_tp_rms"] >= 3.0,
    }
    if "large_quad" in result:
        targets["large_time_le_4.5x"] = result["large_quad"]["large_time_over_small_time"] <= 4.5
        targets["large_peak_memory_le_3gb"] = result["large_quad"]["peak_traced_memory_mb"] <= 3072
    if "phase_correlate" in result:
        pc = result["phase_correlate"]
        targets["faster_than_phase_correlate"] = pc["time_over_tp_time"] > 1
        targets["more_accurate_than_phase_correlate"] = pc["rms_over_tp_rms"] > 1
    return targets


def worst_of(quads: list[dict[str, Any]]) -> dict[str, Any]:
    """The worst figure of each kind over the quads (not necessarily one quad's)."""
    return {
        "sgbm_time_over_tp_time": min(q["sgbm_time_over_tp_time"] for q in quads),
        "sgbm_cpu_over_tp_cpu": min(q["sgbm_cpu_over_tp_cpu"] for q in quads),
        "tp_seconds": max(q["tp_seconds"] for q in quads),
        "tp_rms_fronto_all_px": max(q["tp"]["rms_fronto_all_px"] for q in quads),
        "tp_rms_slanted_px": max(q["tp"]["rms_px"]["slanted"] for q in quads),
        "sgbm_rms_over_tp_rms": min(
            q["sgbm"]["rms_fronto_all_px"] / q["tp"]["rms_fronto_all_px"] for q in quads
        ),
    }


def arguments() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=2592)
    ap.add_argument("--height", type=int, default=1936)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3], help="one quad per seed")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument(
        "--repeat", type=int, default=5, help="timing rounds, TP and SGBM taking turns (best)"
    )
    ap.add_argument("--skip-phase-correlate", action="store_true")
    ap.add_argument(
        "--skip-large", action="store_true", help="skip the quad of twice the width and height"
    )
    add_calibrated_options(ap)
    return ap.parse_args()


def main() -> int:
    args = arguments()
    quads = [render(args.width, args.height, seed) for seed in args.seeds]
    config = TpConfig(threads=args.threads, refine_passes=1)
    load_before = os.getloadavg()[0]
    _, peak = traced_tp(quads[0].quad, config)  # traced runs are slower: not timed
    turns = timed_turns(quads, config, args.repeat)
    results = per_quad(quads, config, turns)
    tp_s = min(turns.tp[0])
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
        },
        "image": {
            "width": args.width,
            "height": args.height,
            "bayer": quads[0].rig.bayer,
            "tiles": int(np.prod(quads[0].quad.tiles)),
        },
        "quads": results,
        "worst_quad": worst_of(results),
        "tile_processor": {
            "peak_traced_memory_mb": round(peak / 2**20, 1),
            "stage_seconds_summed_over_threads": {k: round(v, 3) for k, v in turns.stages.items()},
            "stage_fraction": {
                k: round(v / max(sum(turns.stages.values()), 1e-12), 3)
                for k, v in turns.stages.items()
            },
            "matmul": matmul_figures(quads[0], config, args.threads, tp_s),
        },
    }
    if not args.skip_large:
        result["large_quad"] = large_quad(args, config, quads[0].quad)
    if not args.skip_phase_correlate:
        fronto = results[0]["tp"]["rms_fronto_all_px"]
        result["phase_correlate"] = phase_correlate(quads[0], tp_s, fronto)
    result["conditions"]["max_rss_mb"] = round(
        resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1
    )
    targets = targets_met(result)
    if not args.skip_calibrated:
        result["calibrated"] = calibrated_case(args, quads[0].quad, config, timed_tp)
        targets.update(result["calibrated"].pop("targets_met"))
    result["targets_met"] = targets
    print(json.dumps(result, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
