"""``elphel tp QUAD_DIR --out DSI.tif [--json]``: the tile processor on a quad directory."""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np
import tifffile

from elphel_host.cli import emit
from elphel_host.tp.io import read_quad_dir, write_dsi, write_ml_data
from elphel_host.tp.processor import TpConfig, correlation_tiles, disparity_map
from elphel_host.tp.texture import rendered_images, rgba_texture


def register(subparsers: Any) -> None:
    """Add the ``tp`` subcommand."""
    p = subparsers.add_parser(
        "tp",
        help="disparity space image (DSI) of a quad directory",
        description="Tile processor: per-tile sub-pixel disparity and strength of a quad image set "
        "(DESIGN 4.4 in, 4.5 out).",
    )
    p.add_argument("quad_dir", metavar="QUAD_DIR", help="quad directory (quad.json + cam0..3.tif)")
    p.add_argument("--out", required=True, metavar="DSI.tif", help="output ImageJ TIFF stack")
    p.add_argument(
        "--refine", type=int, default=1, metavar="N", help="refinement passes (default 1)"
    )
    p.add_argument(
        "--scan",
        type=float,
        nargs="+",
        default=[0.0],
        metavar="D",
        help="first-pass target disparities; each tile keeps the strongest (default 0)",
    )
    p.add_argument(
        "--fat-zero", type=float, default=TpConfig.fat_zero, help="fat zero (full scale = 1)"
    )
    p.add_argument("--threads", type=int, default=TpConfig.threads, help="worker threads")
    p.add_argument(
        "--ml-data", metavar="PATH", help="also write the correlation tiles in ML_DATA layout"
    )
    p.add_argument(
        "--texture",
        metavar="PATH",
        help="also write an RGBA float32 TIFF: the four cameras blended at the measured disparity",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    qs = read_quad_dir(args.quad_dir)
    config = TpConfig(
        refine_passes=args.refine,
        scan=tuple(args.scan),
        fat_zero=args.fat_zero,
        threads=args.threads,
    )
    t0 = time.perf_counter()
    dsi = disparity_map(qs.quad, config=config)
    seconds = time.perf_counter() - t0
    h, w = qs.quad.images.shape[1:]
    write_dsi(
        args.out,
        dsi,
        image_size=(w, h),
        geometry=qs.quad.geometry,
        bayer=qs.quad.bayer,
        extra={"fatZero": config.fat_zero, "refinePasses": config.refine_passes},
    )
    result: dict[str, Any] = {
        "dsi": str(args.out),
        "tiles_x": int(dsi["disparity"].shape[1]),
        "tiles_y": int(dsi["disparity"].shape[0]),
        "layers": list(dsi),
        "seconds": round(seconds, 3),
        "disparity_median": float(np.nanmedian(dsi["disparity"])),
        "strength_median": float(np.nanmedian(dsi["strength"])),
    }
    if args.ml_data:
        corr = correlation_tiles(qs.quad, dsi["target_disparity"], config=config)
        write_ml_data(
            args.ml_data, corr, dsi["target_disparity"], extra={"fatZero": config.fat_zero}
        )
        result["ml_data"] = str(args.ml_data)
    if args.texture:
        rendered = rendered_images(qs.quad, dsi["disparity"])
        rgba = rgba_texture(rendered, bayer=qs.quad.bayer)
        tifffile.imwrite(args.texture, rgba, photometric="rgb", extrasamples=["unassalpha"])
        result["texture"] = str(args.texture)
    human = (
        f"{result['dsi']}: {result['tiles_x']}x{result['tiles_y']} tiles, {len(dsi)} layers, "
        f"{seconds:.2f} s; median disparity {result['disparity_median']:.3f} px"
    )
    emit(args, result, human)
    return 0
