"""Super-resolved depth benchmark: five ways to the tile processor's input, scored on the truth.

Renders the simulator's relief scene (`elphel_sim.relief`: wall, three steps, slanted
plane, cylinder; texture to 1 cycle/px; GRBG; shot and read noise of a 12-bit sensor) as
a quad burst of 16 frames planned for x2 (`elphel burst plan --bayer`) along the stage
axis at atan(1/4), and the true surface as a dense cloud (every 0.5 px). Then, with the
same geometry and strength threshold:

- ``lr``: the tile processor on frame 0 (the low-resolution quad, Bayer);
- ``bicubic``: on frame 0 up-sampled x2 (bicubic, per colour), as luminance;
- ``lr_mean``: on each camera's burst averaged at low resolution after moving every
  frame back by its parallax (``D(p) * v_k``, the same per-pixel motion model as ``mfsr``;
  denoising without super-resolution);
- ``mfsr``: `elphel depth` (x2 per camera, per-pixel parallax motion, TP on the fused quad);
- ``hr``: on a quad rendered directly at twice the resolution (the upper bound).

Per method: cloud-to-cloud distances of its cloud to the truth (mean, median, p95, max),
points above the threshold, and the disparity RMS at tile centres in low-resolution
pixels (tiles above the threshold whose footprint lies on one surface). ``seconds`` and
``depth_peak_rss_mb`` are those of the `elphel depth` command run as a user runs it (its
own process, reading the quad burst's TIFFs and writing every product), with its
per-stage ``stage_seconds``. Prints one JSON object; nothing is hard-coded.

    .venv/bin/python bench/depth.py [--width 320 --height 240 --frames 16 --seed 0]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from elphel_host.burst.io import read_quad_burst
from elphel_host.cloud.compare import compare_clouds
from elphel_host.cloud.ply import PointCloud
from elphel_host.depth.geometry import DepthOptics
from elphel_host.depth.pipeline import luminance, tp_config
from elphel_host.depth.products import DEFAULT_MIN_STRENGTH, dsi_depth
from elphel_host.mfsr.fuse import fuse_frames
from elphel_host.mfsr.local_motion import camera_view_disparity, disparity_field, pixel_disparity
from elphel_host.tp.dsi import read_dsi
from elphel_host.tp.images import QuadImages
from elphel_host.tp.io import read_quad_dir
from elphel_host.tp.processor import disparity_map
from elphel_host.tp.texture import demosaic
from elphel_sim import relief
from elphel_sim.quad import QuadRig
from elphel_sim.scenarios import QUAD_RIG_AXIS_DEG

F32 = np.float32


def bayer_luma(raw: np.ndarray, bayer: str | None) -> np.ndarray:
    """Bilinear demosaic (R, B, G planes) to luminance."""
    planes = demosaic(raw, bayer)
    if bayer is None:
        return planes[0]
    return luminance(np.stack([planes[0], planes[2], planes[1]], axis=-1))


def truth_disparity(
    scene: relief.QuadScene, xs: np.ndarray, ys: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """True disparity (LR px) at LR continuous pixel coordinates, and an interior mask."""
    depth, label = relief.cast(scene, xs, ys)
    interior = label >= 0
    for dx, dy in ((-12, 0), (12, 0), (0, -12), (0, 12), (-9, -9), (9, 9), (-9, 9), (9, -9)):
        interior &= relief.cast(scene, xs + dx, ys + dy)[1] == label
    return scene.rig.disparity_px(depth), interior


def score(
    name: str,
    dsi: dict[str, np.ndarray],
    quad: QuadImages,
    optics: DepthOptics,
    scale: int,
    scene: relief.QuadScene,
    reference: PointCloud,
    min_strength: float,
) -> dict[str, Any]:
    res = dsi_depth(dsi, quad, optics, min_strength=min_strength)
    c = compare_clouds(res.cloud, reference, workers=2)
    ty, tx = dsi["disparity"].shape
    yy, xx = np.meshgrid(8.0 * np.arange(ty) + 4, 8.0 * np.arange(tx) + 4, indexing="ij")
    true_d, interior = truth_disparity(scene, xx / scale, yy / scale)
    kept = np.isfinite(res.depth_mm) & interior
    err = dsi["disparity"][kept] / scale - true_d[kept]
    return {
        "c2c_mean_mm": c.forward.mean_mm,
        "c2c_median_mm": c.forward.median_mm,
        "c2c_p95_mm": c.forward.p95_mm,
        "c2c_max_mm": c.forward.max_mm,
        "c2c_std_mm": c.forward.std_mm,
        "reference_to_cloud_mean_mm": c.backward.mean_mm,
        "points": len(res.cloud),
        "tiles": res.tiles,
        "disparity_rms_px": float(np.sqrt(np.mean(err**2))) if err.size else float("nan"),
        "disparity_tiles": int(err.size),
    }


def lr_mean_quad(qb: Any, field: np.ndarray, full: float) -> np.ndarray:
    """Each camera's frames moved back by their parallax and averaged (luminance, LR)."""
    from elphel_host.depth.pipeline import parallax_model

    optics = DepthOptics.from_optics(qb.manifest.optics, source="bench")
    h, w = qb.bursts[0].frames.shape[1:]
    # the per-pixel disparity in each camera's view, as `elphel depth` uses it
    centre = pixel_disparity(field, (h, w))
    ys, xs = np.mgrid[0:h, 0:w].astype(F32)
    out = []
    for cam, burst in enumerate(qb.bursts):
        model = parallax_model(qb, cam, optics)
        assert model is not None
        dpx = camera_view_disparity(centre, qb.manifest.geometry.positions[cam])
        acc = np.zeros((h, w), F32)
        for k, frame in enumerate(burst.frames):
            lum = bayer_luma(frame.astype(F32) / F32(full), qb.manifest.bayer)
            vy, vx = model.per_disparity[k]
            # frame_k(p) ~ ref(p + shift): ref(q) ~ frame_k(q - shift)
            mapx = (xs - dpx * F32(vx)).astype(F32)
            mapy = (ys - dpx * F32(vy)).astype(F32)
            acc += cv2.remap(lum, mapx, mapy, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        out.append(acc / F32(len(burst.frames)))
    return np.stack(out).astype(F32)


def run_elphel_depth(root: Path, scale: int, args: Any) -> tuple[dict[str, Any], float, float]:
    """`elphel depth` on root/qb into root/depth: its JSON, wall seconds and peak RSS (MB)."""
    cmd = [
        str(Path(sys.executable).with_name("elphel")), "depth", str(root / "qb"),
        "--scale", str(scale), "--out", str(root / "depth"),
        "--min-strength", str(args.min_strength), "--threads", str(args.threads), "--json",
    ]  # fmt: skip
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"elphel depth failed ({proc.returncode}): {proc.stderr.strip()}")
    result = json.loads(proc.stdout)
    return result, seconds, result["peak_memory_mb"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scale", type=int, default=2)
    ap.add_argument("--min-strength", type=float, default=DEFAULT_MIN_STRENGTH)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    S = args.scale
    load_before = os.getloadavg()[0]
    rig = QuadRig(width=args.width, height=args.height)
    scene = relief.relief_scene(rig, seed=args.seed)
    positions = relief.burst_positions_mm(rig, scale=S)[: args.frames]
    times: dict[str, float] = {}
    tmp = tempfile.TemporaryDirectory()
    root = Path(tmp.name)
    t0 = time.perf_counter()
    relief.simulate_quad_burst(
        root / "qb", scene, positions, axis_angle_deg=QUAD_RIG_AXIS_DEG, seed=args.seed
    )
    hr_raw = relief.render_quad_at(scene, seed=args.seed + 7, scale=S)
    times["render_s"] = time.perf_counter() - t0
    qb = read_quad_burst(root / "qb")
    reference = relief.surface_cloud(scene, step_px=0.5)
    full = float(qb.manifest.full_scale_dn or 4095)
    optics = DepthOptics.from_optics(qb.manifest.optics, source="bench")
    bayer = qb.manifest.bayer
    geometry = qb.manifest.geometry
    methods: dict[str, Any] = {}
    common = {"scene": scene, "reference": reference, "min_strength": args.min_strength}

    # (a) one LR quad, Bayer as captured
    lr = QuadImages(
        np.stack([b.frames[0].astype(F32) for b in qb.bursts]) / F32(full), bayer=bayer,
        geometry=geometry,
    )  # fmt: skip
    lr_dsi = disparity_map(lr, config=tp_config(1, threads=args.threads))
    methods["lr"] = score("lr", lr_dsi, lr, optics, 1, **common)

    # (b) bicubic x2 of frame 0
    bic = np.stack(
        [luminance(fuse_frames([b.frames[0]], scale=S, method="bicubic", bayer=bayer).image)
         for b in qb.bursts]
    ) / F32(full)  # fmt: skip
    bq = QuadImages(bic.astype(F32), geometry=geometry)
    methods["bicubic"] = score(
        "bicubic", disparity_map(bq, config=tp_config(S, threads=args.threads)), bq,
        optics.scaled(S), S, **common,
    )  # fmt: skip

    # (c) registered mean at LR (parallax from the LR prior)
    field = disparity_field(lr_dsi["disparity"], lr_dsi["strength"], min_strength=args.min_strength)
    mq = QuadImages(lr_mean_quad(qb, field, full), geometry=geometry)
    methods["lr_mean"] = score(
        "lr_mean", disparity_map(mq, config=tp_config(1, threads=args.threads)), mq, optics, 1,
        **common,
    )  # fmt: skip

    # (d) `elphel depth` as a user runs it: its own process, reading the quad burst and
    # writing every product; scored on the DSI and the fused quad it wrote
    depth, depth_seconds, depth_rss_mb = run_elphel_depth(root, S, args)
    fused = read_quad_dir(root / "depth" / "fused")
    methods["mfsr"] = score(
        "mfsr", read_dsi(root / "depth" / "dsi.tif")[0], fused.quad,
        DepthOptics.from_optics(fused.manifest.optics, source="elphel depth"), S, **common,
    )  # fmt: skip

    # (e) rendered directly at x2
    hq = QuadImages(
        np.stack([bayer_luma(im.astype(F32) / F32(full), bayer) for im in hr_raw]).astype(F32),
        geometry=geometry,
    )
    methods["hr"] = score(
        "hr", disparity_map(hq, config=tp_config(S, threads=args.threads)), hq, optics.scaled(S),
        S, **common,
    )  # fmt: skip

    m = methods

    def lower(a: str, b: str) -> float:
        return 1.0 - m[a]["c2c_mean_mm"] / m[b]["c2c_mean_mm"]

    gap = m["lr"]["disparity_rms_px"] - m["hr"]["disparity_rms_px"]
    result = {
        "scene": {
            "width": args.width, "height": args.height, "frames": len(positions),
            "scale": S, "seed": args.seed, "min_strength": args.min_strength,
            "travel_mm": positions[-1] - positions[0], "reference_points": len(reference),
            "depth_range_mm": [float(reference.xyz[:, 2].min()), float(reference.xyz[:, 2].max())],
        },
        "methods": methods,
        "mfsr_vs": {
            "mean_lower_than_lr": lower("mfsr", "lr"),
            "mean_lower_than_bicubic": lower("mfsr", "bicubic"),
            "mean_lower_than_lr_mean": lower("mfsr", "lr_mean"),
            "points_ratio_to_lr": m["mfsr"]["points"] / max(1, m["lr"]["points"]),
            "disparity_gap_closed": (m["lr"]["disparity_rms_px"] - m["mfsr"]["disparity_rms_px"])
            / gap if gap else float("nan"),
        },
        "targets": {"mean_lower_than_lr": 0.30, "mean_lower_than_bicubic": 0.15,
                    "mean_lower_than_lr_mean": 0.10, "points_ratio_to_lr": 3.5},
        "seconds": depth_seconds,
        "stage_seconds": depth["seconds"],
        "depth_peak_rss_mb": depth_rss_mb,
        "fusion": depth["cameras"]["cam0"],
        "render_seconds": times["render_s"],
        "bench_peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "machine": {"cpus": os.cpu_count(), "load_before": load_before,
                    "load_after": os.getloadavg()[0], "python": platform.python_version()},
    }  # fmt: skip
    json.dump(result, sys.stdout, sort_keys=True)
    print()


if __name__ == "__main__":
    main()
