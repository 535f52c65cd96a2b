"""``elphel jp4 convert PATH... --out DIR [--quad | --burst] [--json]``: Elphel recordings.

The conversion is :mod:`elphel_host.recordings.conversion`; this module parses the options,
shows progress on stderr and reports each file that failed, then the result.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from elphel_host.cli_common import add_json_option, emit
from elphel_host.progress import ProgressLine
from elphel_host.recordings.conversion import convert
from elphel_host.shown import shown


def register(subparsers: Any) -> None:
    """Add the ``jp4`` subcommand with its ``convert`` action."""
    p = subparsers.add_parser(
        "jp4",
        help="Elphel JP4/JP46 recordings to 16-bit TIFFs, quad or burst directories",
        description="Files an Elphel camera recorded or served (JP4, JP46, mono JPEG).",
    )
    sub = p.add_subparsers(dest="jp4_action", required=True, metavar="ACTION")
    c = sub.add_parser(
        "convert",
        help="decode frames to linear 16-bit TIFFs with their metadata",
        description="Decode JP4/JP46/JPEG frames (files, or directories of .jp4, .jp46, .jpg, "
        ".jpeg files) to linear 16-bit Bayer TIFFs named <stem>.tif, the frame's metadata as "
        "JSON in ImageDescription. A bad file is reported and skipped (exit 1 at the end); "
        "outputs already complete are skipped, so an interrupted run can be resumed.",
    )
    c.add_argument("paths", nargs="+", metavar="PATH", help="frame files or directories")
    c.add_argument("--out", required=True, metavar="DIR", help="output directory")
    group = c.add_mutually_exclusive_group()
    group.add_argument(
        "--quad",
        action="store_true",
        help="group <sec>_<usec>_<channel> files of one timestamp, channels 0..3, into quad "
        "directories DIR/<sec>_<usec>/ (quad.json + cam0..3.tif) for `elphel tp`",
    )
    group.add_argument(
        "--burst",
        action="store_true",
        help="make each channel's sequence a burst directory DIR/channel<N>/ for `elphel mfsr`",
    )
    c.add_argument("--workers", type=_positive, metavar="N", help="threads (default: every core)")
    add_json_option(c)
    c.set_defaults(func=run_convert)


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}; allowed: an integer >= 1")
    return value


def run_convert(args: argparse.Namespace) -> int:
    layout = "quad" if args.quad else "burst" if args.burst else "files"
    line = ProgressLine()

    def progress(done: int, total: int, name: str) -> None:
        line.update(f"converting {done}/{total}: {name}", done=done, total=total)

    try:
        result = convert(
            args.paths, args.out, layout=layout, workers=args.workers, progress=progress
        )
    finally:
        line.end()
    for failure in result.failed:
        print(f"elphel: {shown(failure.reason, limit_chars=500)}", file=sys.stderr)
    written = sum(not c.skipped for c in result.converted)
    skipped = len(result.converted) - written
    human = (
        f"{written} converted, {skipped} already done, {len(result.failed)} failed -> {args.out}"
    )
    if result.directories:
        kind = "quad" if args.quad else "burst"
        human += f"\n{len(result.directories)} {kind} directories: "
        human += ", ".join(d.name for d in result.directories)
    emit(args, {"out": str(args.out), "layout": layout, **result.to_json()}, human)
    return 1 if result.failed else 0
