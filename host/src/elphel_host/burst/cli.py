"""``elphel burst plan|capture``: plan a sub-pixel burst and capture it (burst/capture.py)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from elphel_host.burst.capture import add_capture_parser
from elphel_host.burst.plan import plan_burst
from elphel_host.cli_common import emit


def register(subparsers: Any) -> None:
    """Add the ``burst`` subcommand with its ``plan`` and ``capture`` actions."""
    p = subparsers.add_parser(
        "burst",
        help="plan (and capture) sub-pixel bursts",
        description="Sub-pixel bursts for multi-frame super-resolution.",
    )
    sub = p.add_subparsers(dest="burst_action", required=True, metavar="ACTION")
    pl = sub.add_parser(
        "plan",
        help="stage positions giving the sub-pixel phases a scale needs",
        description="Positions along the stage axis for a x S burst, the "
        "recommended mount tilt (tan theta = 1/S; 1/(2S) with --bayer) and the parallax limit.",
    )
    pl.add_argument("--scale", type=int, required=True, metavar="S")
    pl.add_argument("--focal-length-mm", type=float, required=True, metavar="F")
    pl.add_argument("--pixel-pitch-um", type=float, required=True, metavar="P")
    pl.add_argument(
        "--distance-mm",
        type=float,
        required=True,
        metavar="Z",
        help="distance of the object plane from the lens",
    )
    pl.add_argument("--mm-per-step", type=float, metavar="M", help="round to whole stage steps")
    pl.add_argument(
        "--frames", type=int, metavar="N", help="number of frames (default S*S, Bayer (2S)^2)"
    )
    pl.add_argument(
        "--bayer",
        action="store_true",
        help="plan for a Bayer sensor: the phases of each colour's 2 px period "
        "(tan theta = 1/(2S))",
    )
    pl.add_argument("--out", metavar="plan.json", help="save the plan as JSON")
    pl.add_argument("--json", action="store_true", help="print one JSON object")
    pl.set_defaults(func=run_plan)
    add_capture_parser(sub)


def run_plan(args: argparse.Namespace) -> int:
    plan = plan_burst(
        scale=args.scale,
        focal_length_mm=args.focal_length_mm,
        pixel_pitch_um=args.pixel_pitch_um,
        distance_mm=args.distance_mm,
        mm_per_step=args.mm_per_step,
        frames=args.frames,
        bayer=args.bayer,
    )
    result = plan.to_json()
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
        result["out"] = str(args.out)
    lines = [
        f"x{plan.scale} {'Bayer ' if plan.bayer else ''}burst, {plan.frames} frames, "
        f"{plan.px_per_mm:.2f} px/mm at the "
        f"object plane, travel {plan.travel_mm:.4f} mm"
    ]
    for i, (p, sh) in enumerate(zip(plan.positions_mm, plan.shifts_px, strict=True)):
        st = f"  step {plan.steps[i]}" if plan.steps is not None else ""
        lines.append(f"  {i:3d}: {p:.5f} mm{st}  shift dy={sh[0]:.3f} dx={sh[1]:.3f} px")
    lines += [f"note: {n}" for n in plan.notes]
    if args.out:
        lines.append(f"saved {args.out}")
    emit(args, result, "\n".join(lines))
    return 0
