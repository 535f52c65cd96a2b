"""``elphel-camd vospi-record``: record a Lepton's VoSPI stream for replay or a bug report.

The recording replays through ``elphel-camd --board lepton --vospi FILE`` into the same
frames (`elphel_camd.vospi.record`).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from elphel_camd.vospi.errors import VoSPIError, VoSPITimeoutError
from elphel_camd.vospi.record import record_stream
from elphel_camd.vospi.sources import MAX_CLOCK_HZ


def build_record_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="elphel-camd vospi-record",
        description="Record a Lepton's VoSPI stream (the bytes the reader consumes) to a "
        "file that replays with: elphel-camd --board lepton --vospi FILE",
    )
    p.add_argument("vospi", help="the Lepton's spidev node, e.g. /dev/spidev0.0")
    p.add_argument("--out", type=Path, required=True, help="the recording to write")
    p.add_argument("--frames", type=int, help="stop after this many whole frames")
    p.add_argument("--seconds", type=float, help="stop after this long")
    p.add_argument(
        "--spi-clock-hz", type=int, default=MAX_CLOCK_HZ, help="SPI clock (default 20 MHz)"
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    return p


def record_main(argv: Sequence[str]) -> int:
    """Record until ``--frames`` or ``--seconds``; exit 1 with one line on failure."""
    parser = build_record_parser()
    args = parser.parse_args(argv)
    if args.frames is None and args.seconds is None:
        parser.error("give --frames or --seconds")
    try:
        summary = record_stream(
            args.vospi,
            args.out,
            frames=args.frames,
            seconds=args.seconds,
            clock_hz=args.spi_clock_hz,
        )
    except (VoSPIError, VoSPITimeoutError, OSError) as e:
        print(f"elphel-camd vospi-record: {e}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(summary))
    else:
        print(
            f"recorded {summary['frames']} frames ({summary['bytes']} bytes, "
            f"{summary['resyncs']} resyncs) from {summary['path']} to {summary['out']}"
        )
    return 0
