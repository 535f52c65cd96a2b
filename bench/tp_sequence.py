"""Sequence throughput of the tile processor: many quads on a local Dask cluster vs one process.

Renders a few distinct simulated 2592x1936 quads (the standard scene, different noise
seeds) and lays them out as a sequence of ``--quads`` quad directories (hard links to
the rendered files). In the same run it computes every DSI

* one after another in this process, with the same options as each cluster task
  (one thread: ``sequential_1_thread``) and with the single-quad command's default of two
  threads (``sequential_default_threads``), and
* through ``elphel tp QUAD_DIR... --out-dir DIR`` on a local cluster (one worker process
  per core, one quad per task),

and checks that the cluster's DSIs are bit for bit the sequential ones. The single-threaded
sequence and the cluster take turns, twice, in the order sequential, cluster, cluster,
sequential (``--rounds``), and the ratio is of their summed times: how fast the host runs
the two vCPUs drifts by 10-20 % over minutes, and a drift that is linear in time then
favours neither side. Both sides' imports in this process are done before anything is
timed; the cluster's start, its worker processes and their imports, is timed in every
turn. The worker processes import the script that started them as their main module:
this script's top level imports what the `elphel` command's does (``elphel_host.cli``)
and no more, so that its workers start as the command's do (with the simulator and the
tile processor imported at the top, a local cluster took 0.74-0.89 s to start instead
of 0.43-0.49 s). Prints exactly one JSON object; nothing is hard-coded.

    .venv/bin/python bench/tp_sequence.py [--quads 40 --distinct 2 --width 2592 --height 1936]
                                          [--rounds 2]
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
from typing import TYPE_CHECKING, Any

from elphel_host.cli import main as elphel

if TYPE_CHECKING:
    from elphel_host.tp.config import TpConfig


def make_sequence(root: Path, n: int, distinct: int, width: int, height: int) -> list[Path]:
    """``n`` quad directories cycling over ``distinct`` rendered quads (hard links)."""
    from elphel_sim import quad as simquad

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
    from elphel_host.tp.sequence import dsi_of_quad

    out.mkdir(parents=True)
    t0 = time.perf_counter()
    for q in quads:
        dsi_of_quad(q, out / f"{q.name}.tif", config)
    return time.perf_counter() - t0


def cluster(sequence: Path, out: Path, workers: int) -> tuple[float, dict[str, Any]]:
    """``elphel tp SEQUENCE --out-dir OUT`` on a local cluster: seconds (cluster start
    included) and the command's JSON report."""
    buf = stdio.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(stdio.StringIO()):
        args = ["tp", str(sequence), "--out-dir", str(out), "--workers", str(workers), "--json"]
        rc = elphel(args)
    seconds = time.perf_counter() - t0
    report: dict[str, Any] = json.loads(buf.getvalue())
    report["rc"] = rc
    return seconds, report


def same_dsis(a: Path, b: Path, names: list[str]) -> bool:
    import numpy as np

    from elphel_host.tp import dsi as dsi_io

    for n in names:
        x, y = dsi_io.read_dsi(a / f"{n}.tif")[0], dsi_io.read_dsi(b / f"{n}.tif")[0]
        if list(x) != list(y):
            return False
        if not all(np.array_equal(x[k], y[k], equal_nan=True) for k in x):
            return False
    return True


def main() -> int:
    import numpy as np

    from elphel_host.tp.config import TpConfig

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quads", type=int, default=40)
    ap.add_argument("--distinct", type=int, default=2, help="distinct rendered quads")
    ap.add_argument("--width", type=int, default=2592)
    ap.add_argument("--height", type=int, default=1936)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--rounds", type=int, default=2, help="turns of sequential and cluster")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="tp_sequence_") as tmp:
        root = Path(tmp)
        t0 = time.perf_counter()
        quads = make_sequence(root, args.quads, args.distinct, args.width, args.height)
        render_s = time.perf_counter() - t0
        names = [q.name for q in quads]
        # what either side imports in this process on its first run
        import dask.distributed  # noqa: F401

        import elphel_host.tp.cli
        import elphel_host.tp.sequence  # noqa: F401

        load_before = os.getloadavg()[0]
        one = TpConfig(threads=1)
        seq1_runs: list[float] = []
        cluster_runs: list[float] = []
        identical = True
        failed = 0
        for r in range(args.rounds):
            # taking turns: sequential, cluster, cluster, sequential, ...
            for side in ("sequential", "cluster") if r % 2 == 0 else ("cluster", "sequential"):
                if side == "sequential":
                    seq1_runs.append(sequential(quads, root / f"seq1-{r}", one))
                    continue
                seconds, report = cluster(root / "sequence", root / f"cluster-{r}", args.workers)
                cluster_runs.append(seconds)
                failed += report["failed"]
                identical &= report["rc"] == 0 and same_dsis(
                    root / "seq1-0", root / f"cluster-{r}", names
                )
        seq2_s = sequential(quads, root / "seq2", replace(one, threads=TpConfig().threads))
        identical_threads = same_dsis(root / "seq1-0", root / "seq2", names)
    seq1_s, cluster_s = sum(seq1_runs), sum(cluster_runs)
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
        "sequential_1_thread": {
            "runs_s": [round(t, 3) for t in seq1_runs],
            "quads_per_s": args.quads * len(seq1_runs) / seq1_s,
        },
        "sequential_default_threads": {
            "threads": TpConfig().threads,
            "seconds": round(seq2_s, 3),
            "quads_per_s": args.quads / seq2_s,
        },
        "local_cluster": {
            "workers": args.workers,
            "runs_s_including_cluster_start": [round(t, 3) for t in cluster_runs],
            "failed_quads": failed,
            "quads_per_s": args.quads * len(cluster_runs) / cluster_s,
        },
        "ratios": {
            "sequential_1_thread_time_over_cluster_time": round(seq1_s / cluster_s, 3),
            "per_round": [round(a / b, 3) for a, b in zip(seq1_runs, cluster_runs, strict=True)],
            "sequential_default_threads_time_over_cluster_time": round(
                seq2_s * len(cluster_runs) / cluster_s, 3
            ),
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
