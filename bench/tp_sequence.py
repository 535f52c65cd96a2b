"""Sequence throughput of the tile processor: many quads on a local Dask cluster vs one process.

Renders a few distinct simulated 2592x1936 quads (the standard scene, different noise
seeds) and lays them out as a sequence of ``--quads`` quad directories (hard links to
the rendered files). In the same run it computes every DSI

* one after another in this process, with the same options as each cluster task
  (one thread: ``sequential_1_thread``) and with the single-quad command's default of two
  threads (``sequential_default_threads``), and
* through ``elphel tp QUAD_DIR... --out-dir DIR`` on a local cluster (one worker process
  per core, one quad per task),

and checks that the cluster's DSIs are bit for bit the sequential ones. Prints exactly
one JSON object; nothing is hard-coded.

    .venv/bin/python bench/tp_sequence.py [--quads 40 --distinct 2 --width 2592 --height 1936]
"""

from __future__ import annotations

import argparse
import contextlib
import io as stdio
import json
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from elphel_host.cli import main as elphel
from elphel_host.tp import dsi as dsi_io
from elphel_host.tp.config import TpConfig
from elphel_host.tp.sequence import dsi_of_quad
from elphel_sim import quad as simquad


def make_sequence(root: Path, n: int, distinct: int, width: int, height: int) -> list[Path]:
    """``n`` quad directories cycling over ``distinct`` rendered quads (hard links)."""
    rig = simquad.QuadRig(width=width, height=height)
    sources = []
    for k in range(distinct):
        src, _ = simquad.simulate_quad_dir(root / f"source{k}", rig, seed=k)
        sources.append(src)
    quads = []
    for i in range(n):
        src = sources[i % distinct]
        dst = root / "sequence" / f"frame{i:04d}"
        dst.mkdir(parents=True)
        for f in src.iterdir():
            os.link(f, dst / f.name)
        quads.append(dst)
    return quads


def sequential(quads: list[Path], out: Path, config: TpConfig) -> float:
    out.mkdir(parents=True)
    t0 = time.perf_counter()
    for q in quads:
        dsi_of_quad(q, out / f"{q.name}.tif", config)
    return time.perf_counter() - t0


def same_dsis(a: Path, b: Path, names: list[str]) -> bool:
    for n in names:
        x, y = dsi_io.read_dsi(a / f"{n}.tif")[0], dsi_io.read_dsi(b / f"{n}.tif")[0]
        if list(x) != list(y):
            return False
        if not all(np.array_equal(x[k], y[k], equal_nan=True) for k in x):
            return False
    return True


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quads", type=int, default=40)
    ap.add_argument("--distinct", type=int, default=2, help="distinct rendered quads")
    ap.add_argument("--width", type=int, default=2592)
    ap.add_argument("--height", type=int, default=1936)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="tp_sequence_") as tmp:
        root = Path(tmp)
        t0 = time.perf_counter()
        quads = make_sequence(root, args.quads, args.distinct, args.width, args.height)
        render_s = time.perf_counter() - t0
        names = [q.name for q in quads]
        load_before = os.getloadavg()[0]
        one = TpConfig(threads=1)
        seq1_s = sequential(quads, root / "seq1", one)
        seq2_s = sequential(quads, root / "seq2", replace(one, threads=TpConfig().threads))
        buf = stdio.StringIO()
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(stdio.StringIO()):
            rc = elphel(
                [
                    "tp",
                    str(root / "sequence"),
                    "--out-dir",
                    str(root / "cluster"),
                    "--workers",
                    str(args.workers),
                    "--json",
                ]
            )
        cluster_s = time.perf_counter() - t0
        report = json.loads(buf.getvalue())
        identical = rc == 0 and same_dsis(root / "seq1", root / "cluster", names)
        identical_threads = same_dsis(root / "seq1", root / "seq2", names)
    result: dict[str, Any] = {
        "conditions": {
            "cpus": os.cpu_count(),
            "load_average_1min_before": load_before,
            "load_average_1min_after": os.getloadavg()[0],
            "python": sys.version.split()[0],
            "numpy": np.__version__,
        },
        "sequence": {
            "quads": args.quads,
            "distinct_renders": args.distinct,
            "width": args.width,
            "height": args.height,
            "render_s": round(render_s, 1),
        },
        "sequential_1_thread": {"seconds": round(seq1_s, 3), "quads_per_s": args.quads / seq1_s},
        "sequential_default_threads": {
            "threads": TpConfig().threads,
            "seconds": round(seq2_s, 3),
            "quads_per_s": args.quads / seq2_s,
        },
        "local_cluster": {
            "workers": args.workers,
            "seconds_including_cluster_start": round(cluster_s, 3),
            "quads_per_s": args.quads / cluster_s,
            "done": report["done"],
            "failed": report["failed"],
        },
        "ratios": {
            "sequential_1_thread_time_over_cluster_time": round(seq1_s / cluster_s, 3),
            "sequential_default_threads_time_over_cluster_time": round(seq2_s / cluster_s, 3),
        },
        "identical_dsis": {
            "cluster_vs_sequential": identical,
            "one_vs_two_threads": identical_threads,
        },
    }
    result["targets_met"] = {
        "cluster_1.7x_faster_than_sequential_1_thread": seq1_s >= 1.7 * cluster_s,
        "identical_dsis": identical,
    }
    print(json.dumps(result, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
