"""``elphel cloud compare COMPARED.ply REFERENCE.ply``: cloud-to-cloud distances.

The distances are :mod:`elphel_host.cloud.compare`, the pictures
:mod:`elphel_host.cloud.render`, the files :mod:`elphel_host.cloud.ply`; this module
parses the options and renders the result.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from elphel_host.cli_common import add_json_option, emit
from elphel_host.cloud.compare import compare_clouds
from elphel_host.cloud.ply import PointCloud, read_ply, write_ply
from elphel_host.cloud.render import histogram_png
from elphel_host.preview import colour_map


def register(subparsers: Any) -> None:
    """Add the ``cloud`` subcommand with its ``compare`` action."""
    p = subparsers.add_parser(
        "cloud",
        help="point clouds: cloud-to-cloud distances",
        description="Point-cloud tools (binary PLY, millimetres).",
    )
    sub = p.add_subparsers(dest="cloud_action", required=True, metavar="ACTION")
    c = sub.add_parser(
        "compare",
        help="distance of each compared point to its nearest reference point, both directions",
        description="Cloud-to-cloud distances as CloudCompare computes them by default: each "
        "point of COMPARED to its nearest point of REFERENCE (KD-tree), and the other way "
        "round. Writes a histogram PNG and a copy of COMPARED coloured by distance.",
    )
    c.add_argument("compared", metavar="COMPARED.ply", type=Path)
    c.add_argument("reference", metavar="REFERENCE.ply", type=Path)
    c.add_argument(
        "--max-distance",
        type=float,
        metavar="MM",
        help="leave distances above MM out of the statistics and count them (default: keep all)",
    )
    c.add_argument(
        "--out-dir",
        type=Path,
        metavar="DIR",
        help="where to write STEM_c2c.ply and STEM_c2c_hist.png (default: beside COMPARED)",
    )
    c.add_argument("--workers", type=int, default=1, metavar="N", help="KD-tree query threads")
    add_json_option(c)
    c.set_defaults(func=run_compare, parser=c)


def run_compare(args: argparse.Namespace) -> int:
    """Compare two clouds, write the coloured copy and the histogram, print the statistics."""
    if args.max_distance is not None and not args.max_distance > 0:
        args.parser.error(f"--max-distance {args.max_distance:g}; allowed: > 0")
    if args.workers < 1:
        args.parser.error(f"--workers {args.workers}; allowed: >= 1")
    compared = read_ply(args.compared)
    reference = read_ply(args.reference)
    result = compare_clouds(
        compared, reference, max_distance_mm=args.max_distance, workers=args.workers
    )
    out_dir = args.out_dir if args.out_dir is not None else args.compared.parent
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = args.compared.stem
    d = result.distances_mm
    shown = d if args.max_distance is None else np.minimum(d, args.max_distance)
    hi = float(np.percentile(shown, 99)) if shown.size else 1.0
    scalars = {k: v for k, v in compared.scalars.items() if k != "distance"}
    scalars["distance"] = d.astype(np.float32)
    coloured = PointCloud(compared.xyz, compared.strength, colour_map(shown, 0.0, hi), scalars)
    ply = write_ply(
        out_dir / f"{stem}_c2c.ply",
        coloured,
        comments=(f"colour: distance to {args.reference.name}, 0 .. {hi:.4g} mm (viridis)",),
    )
    hist = histogram_png(
        out_dir / f"{stem}_c2c_hist.png",
        d,
        max_mm=args.max_distance,
        title=f"{stem} -> {args.reference.stem}",
    )
    summary: dict[str, Any] = {
        "compared": str(args.compared),
        "reference": str(args.reference),
        "compared_points": len(compared),
        "reference_points": len(reference),
        **result.to_json(),
        "coloured_ply": str(ply),
        "histogram_png": str(hist),
        "colour_range_mm": [0.0, hi],
    }
    f, b = result.forward, result.backward
    human = "\n".join(
        [
            f"{args.compared} ({len(compared)} points) vs {args.reference} ({len(reference)})",
            f"  compared -> reference: mean {f.mean_mm:.4g} mm, std {f.std_mm:.4g}, "
            f"median {f.median_mm:.4g}, p95 {f.p95_mm:.4g}, max {f.max_mm:.4g}"
            + (f", {f.beyond} beyond {args.max_distance:g} mm" if args.max_distance else ""),
            f"  reference -> compared: mean {b.mean_mm:.4g} mm, std {b.std_mm:.4g}, "
            f"median {b.median_mm:.4g}, p95 {b.p95_mm:.4g}, max {b.max_mm:.4g}"
            + (f", {b.beyond} beyond {args.max_distance:g} mm" if args.max_distance else ""),
            f"  coloured copy: {ply}; histogram: {hist}",
        ]
    )
    emit(args, summary, human)
    return 0
