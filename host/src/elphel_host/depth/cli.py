"""``elphel depth QUAD_BURST --scale S --out DIR``: super-resolved depth of a quad burst.

The work is :mod:`elphel_host.depth.pipeline`; this module parses the options, writes
the products and renders the result.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from elphel_host.cli_common import add_json_option, emit, fusion_scale
from elphel_host.depth.pipeline import MOTIONS, DepthConfig, read_and_run, write_fused_quad
from elphel_host.depth.products import (
    DEFAULT_MAX_DISAGREEMENT,
    DEFAULT_MIN_STRENGTH,
    write_depth_products,
)
from elphel_host.fileio import write_atomic
from elphel_host.mfsr.fuse import METHODS, peak_memory_mb
from elphel_host.progress import ProgressLine
from elphel_host.strict_json import report_dumps
from elphel_host.tp.dsi import write_dsi


def register(subparsers: Any) -> None:
    """Add the ``depth`` subcommand."""
    p = subparsers.add_parser(
        "depth",
        help="super-resolved depth map and point cloud of a quad burst",
        description="Fuse each camera's burst of a quad-burst directory (MFSR), run the tile "
        "processor on the fused quad, and write its DSI, a depth map in mm and a point cloud. "
        "When quad.json names a calibration, the bursts are taken as the cameras' raw images "
        "and corrected for it (docs/depth.md, Calibrated quad bursts).",
    )
    p.add_argument("quad_burst", metavar="QUAD_BURST", type=Path, help="quad-burst directory")
    p.add_argument(
        "--scale", type=fusion_scale, default=2, metavar="S", help="up-sampling (default 2)"
    )
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="output directory")
    p.add_argument(
        "--motion",
        choices=MOTIONS,
        default="local",
        help="local: each pixel moves by its disparity times the stage step (parallax), "
        "fused by shift-and-add; global: one shift per frame, fused by --method "
        "(default local)",
    )
    p.add_argument(
        "--method",
        choices=METHODS,
        default=None,
        help="fusion method of --motion global (default robust); bicubic up-samples "
        "the first frames with either motion",
    )
    p.add_argument(
        "--min-strength",
        type=float,
        default=DEFAULT_MIN_STRENGTH,
        metavar="S",
        help=f"tiles weaker than S are left out (default {DEFAULT_MIN_STRENGTH:g})",
    )
    add_disagreement_option(p)
    p.add_argument("--threads", type=int, default=2, metavar="N", help="worker threads")
    add_json_option(p)
    p.set_defaults(func=run, parser=p)


def add_disagreement_option(p: Any) -> None:
    """``--max-disagreement F`` (of ``elphel depth`` and ``elphel tp --ply``)."""
    p.add_argument(
        "--max-disagreement",
        type=float,
        default=DEFAULT_MAX_DISAGREEMENT,
        metavar="F",
        help="tiles whose combined disparity is more than the fraction F away from the "
        "median of their confident horizontal, vertical and diagonal disparities are left "
        f"out (default {DEFAULT_MAX_DISAGREEMENT:g}; 0 keeps them)",
    )


def max_disagreement(args: argparse.Namespace) -> float | None:
    """``--max-disagreement``, checked: None when 0 (no check)."""
    f = args.max_disagreement
    if not f >= 0:
        args.parser.error(f"--max-disagreement {f:g}; allowed: >= 0 (0 keeps every tile)")
    return None if f == 0 else float(f)


def run(args: argparse.Namespace) -> int:
    """Run the depth pipeline and write DIR/dsi.tif, cloud.ply (+ PNG), cloud_depth.tif (+ PNG)."""
    if args.threads < 1:
        args.parser.error(f"--threads {args.threads}; allowed: >= 1")
    if args.motion == "local" and args.method not in (None, "bicubic"):
        args.parser.error(
            f"--method {args.method} fuses with one shift per frame: give --motion global "
            "with it (local motion fuses by parallax shift-and-add)"
        )
    try:
        config = DepthConfig(
            scale=args.scale,
            method=args.method or "robust",
            motion=args.motion,
            min_strength=args.min_strength,
            max_disagreement=max_disagreement(args),
            threads=args.threads,
        )
    except ValueError as e:
        args.parser.error(str(e))
    progress = ProgressLine()
    run_, read_s = read_and_run(args.quad_burst, config=config, progress=progress.update)
    progress.end()
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    h, w = run_.fused.images.shape[1:]
    dsi_path = out / "dsi.tif"
    write_dsi(
        dsi_path,
        run_.dsi,
        image_size=(w, h),
        geometry=run_.fused.geometry,
        bayer=None,
        extra={"scale": config.scale, "disparityUnits": "fused px (disparity_lr: original px)"},
    )
    files = write_depth_products(out / "cloud.ply", run_.depth, run_.optics, title="MFSR")
    fused_dir = write_fused_quad(out / "fused", run_)
    result: dict[str, Any] = {
        "quad_burst": str(args.quad_burst),
        "scale": config.scale,
        "method": config.fusion,
        "motion": config.motion,
        "dsi": str(dsi_path),
        "fused_quad": str(fused_dir),
        **files,
        **run_.depth.summary(),
        "seconds": {"read": round(read_s - run_.seconds["total"], 3)}
        | {k: round(v, 3) for k, v in run_.seconds.items()},
        "cameras": run_.info,
        "peak_memory_mb": round(peak_memory_mb(), 1),
    }
    write_atomic(out / "depth.json", (report_dumps(result, indent=2) + "\n").encode())
    human = (
        f"{out}: {result['points']} points of {result['tiles']} tiles "
        f"({result['weak_tiles']} below strength {config.min_strength:g}, "
        f"{result['infinite_tiles']} at infinity, {result['inconsistent_tiles']} with "
        f"disagreeing directions); {files['ply']}, {files['depth_tiff']}; "
        f"{run_.seconds['total']:.1f} s (fuse {run_.seconds['fuse']:.1f} s)"
    )
    emit(args, result, human)
    return 0
