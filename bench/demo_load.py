"""`make demo` beside CPU-bound processes: does it complete, in how long? Prints ONE JSON object.

Runs the demo (``python -m elphel_sim.demo``, what ``make demo`` runs) with ``--hogs``
processes running ``while True: pass`` beside it for the whole run (default 2: on a
2-core machine the demo then gets a third of the CPU), and, unless ``--no-peer``, the
same demo alone first (the peer). Reported: each run's exit status and seconds, the
last lines of a failed run, the loaded/alone time ratio, and the load average at start.

Usage: python bench/demo_load.py [--hogs 2] [--no-peer] [--timeout-s 3600]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any


def run_demo(out: Path, timeout_s: float) -> dict[str, Any]:
    """One demo into ``out``: its exit status, seconds, and its last lines if it failed."""
    start = time.monotonic()
    try:
        done = subprocess.run(
            [sys.executable, "-m", "elphel_sim.demo", "--out", str(out)],
            capture_output=True,
            text=True,
            timeout=timeout_s,
        )
        code, text = done.returncode, done.stdout + done.stderr
    except subprocess.TimeoutExpired as e:
        code, text = None, f"timed out after {timeout_s} s: {e.stdout or ''}{e.stderr or ''}"
    result: dict[str, Any] = {"exit": code, "seconds": round(time.monotonic() - start, 1)}
    if code != 0:
        result["tail"] = str(text).strip().splitlines()[-8:]
    return result


def with_hogs(count: int, out: Path, timeout_s: float) -> dict[str, Any]:
    """The demo with ``count`` CPU-bound processes beside it; they end with it."""
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]
    try:
        return run_demo(out, timeout_s)
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--hogs", type=int, default=2)
    parser.add_argument("--no-peer", action="store_true", help="skip the demo alone")
    parser.add_argument("--timeout-s", type=float, default=3600.0)
    args = parser.parse_args()
    result: dict[str, Any] = {
        "bench": "demo_load",
        "cpus": os.cpu_count(),
        "load_average_at_start": [round(v, 2) for v in os.getloadavg()],
        "hogs": args.hogs,
    }
    with tempfile.TemporaryDirectory(prefix="demo-load-") as tmp:
        if not args.no_peer:
            result["alone"] = run_demo(Path(tmp) / "alone", args.timeout_s)
        result["loaded"] = with_hogs(args.hogs, Path(tmp) / "loaded", args.timeout_s)
    if "alone" in result and result["alone"]["exit"] == 0 == result["loaded"]["exit"]:
        result["loaded_over_alone"] = round(
            result["loaded"]["seconds"] / result["alone"]["seconds"], 2
        )
    json.dump(result, sys.stdout)
    print()


if __name__ == "__main__":
    main()
