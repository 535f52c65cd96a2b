"""Sequence throughput of the tile processor: many quads on Dask clusters vs one process.

Renders a few distinct simulated 2592x1936 quads (the standard scene, different noise
seeds) and lays them out as a sequence of ``--quads`` quad directories (hard links to
the rendered files). In the same run it computes every DSI

* one after another in this process, with the same options as each cluster task
  (one thread: ``sequential_1_thread``) and with the single-quad command's default of two
  threads (``sequential_default_threads``), and
* through ``elphel tp QUAD_DIR... --out-dir DIR`` on a local cluster (one worker process
  per core, one quad per task), and
* through the same command with ``--scheduler ADDRESS`` on a real cluster on loopback:
  a ``dask scheduler`` and one ``dask worker --nthreads 1`` per core (each with its
  nanny, as a user starts them), started by this script before the first turn with the
  environment docs/tile-processor.md recommends,

and checks that both clusters' DSIs are bit for bit the sequential ones. The
single-threaded sequence and the clusters take turns, twice, in the order sequential,
local, real, real, local, sequential (``--rounds``), and the ratios are of their summed
times: how fast the host runs the two vCPUs drifts by 10-20 % over minutes, and a drift
that is linear in time then favours no side. Every side's imports in this process are
done before anything is timed; the local cluster's start, its worker processes and their
imports, is timed in every turn; the real cluster's first turn includes its workers'
imports of the tile processor. The local cluster's worker processes import the script
that started them as their main module: this script's top level imports what the
`elphel` command's does (``elphel_host.cli``) and no more, so that its workers start as
the command's do (with the simulator and the tile processor imported at the top, a local
cluster took 0.74-0.89 s to start instead of 0.43-0.49 s). Prints exactly one JSON
object; nothing is hard-coded.

    .venv/bin/python bench/tp_sequence.py [--quads 40 --distinct 2 --width 2592 --height 1936]
                                          [--rounds 2] [--workers N]
"""

from __future__ import annotations

import argparse
import contextlib
import io as stdio
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
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


DASK = Path(sys.executable).with_name("dask")
START_TIMEOUT_S = 90.0


@contextlib.contextmanager
def real_cluster(root: Path, workers: int) -> Iterator[str]:
    """``dask scheduler`` and ``workers`` x ``dask worker --nthreads 1`` on 127.0.0.1,
    with the environment docs/tile-processor.md recommends; yields the address, and
    stops the processes afterwards."""
    from dask.distributed import Client

    from elphel_host.parallel import dask_environment

    env = {**os.environ, **dask_environment()}
    sched_file = root / "scheduler.json"
    procs: list[subprocess.Popen[bytes]] = []
    with (root / "dask.log").open("wb") as log:
        try:

            def start(*args: str) -> None:
                cmd = [str(DASK), *args, "--host", "127.0.0.1", "--no-dashboard"]
                procs.append(subprocess.Popen(cmd, stdout=log, stderr=log, env=env))

            start("scheduler", "--port", "0", "--scheduler-file", str(sched_file))
            deadline = time.monotonic() + START_TIMEOUT_S
            while not sched_file.is_file():
                if procs[0].poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"dask scheduler did not start; see {root / 'dask.log'}")
                time.sleep(0.2)
            address = str(json.loads(sched_file.read_text())["address"])
            for _ in range(workers):
                start("worker", address, "--nthreads", "1")
            with Client(address, timeout="30s") as client:
                client.wait_for_workers(workers, timeout=START_TIMEOUT_S)
            yield address
        finally:
            for p in procs:
                p.terminate()
            for p in procs:
                try:
                    p.wait(timeout=15)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()


def cluster(sequence: Path, out: Path, where: list[str]) -> tuple[float, dict[str, Any]]:
    """``elphel tp SEQUENCE --out-dir OUT`` plus ``where`` (``--workers N`` for a local
    cluster, ``--scheduler ADDRESS``): seconds (a local cluster's start included) and the
    command's JSON report."""
    buf = stdio.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(stdio.StringIO()):
        rc = elphel(["tp", str(sequence), "--out-dir", str(out), *where, "--json"])
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
        runs: dict[str, list[float]] = {"sequential": [], "local": [], "real": []}
        identical = {"local": True, "real": True}
        failed = {"local": 0, "real": 0}
        with real_cluster(root, args.workers) as address:
            where = {"local": ["--workers", str(args.workers)], "real": ["--scheduler", address]}
            for r in range(args.rounds):
                # taking turns: sequential, local, real, real, local, sequential, ...
                order = ("sequential", "local", "real")
                for side in order if r % 2 == 0 else order[::-1]:
                    out = root / f"{side}-{r}"
                    if side == "sequential":
                        runs[side].append(sequential(quads, out, one))
                        continue
                    seconds, report = cluster(root / "sequence", out, where[side])
                    runs[side].append(seconds)
                    failed[side] += report["failed"]
                    identical[side] &= report["rc"] == 0 and same_dsis(
                        root / "sequential-0", out, names
                    )
        seq2_s = sequential(quads, root / "seq2", replace(one, threads=TpConfig().threads))
        identical_threads = same_dsis(root / "sequential-0", root / "seq2", names)
    seq1_s, local_s, real_s = (sum(runs[k]) for k in ("sequential", "local", "real"))
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
            "runs_s": [round(t, 3) for t in runs["sequential"]],
            "quads_per_s": args.quads * len(runs["sequential"]) / seq1_s,
        },
        "sequential_default_threads": {
            "threads": TpConfig().threads,
            "seconds": round(seq2_s, 3),
            "quads_per_s": args.quads / seq2_s,
        },
        "local_cluster": {
            "workers": args.workers,
            "runs_s_including_cluster_start": [round(t, 3) for t in runs["local"]],
            "failed_quads": failed["local"],
            "quads_per_s": args.quads * len(runs["local"]) / local_s,
        },
        "real_cluster": {
            "workers": args.workers,
            "processes": "dask scheduler + dask worker --nthreads 1 (with nanny), loopback",
            "runs_s": [round(t, 3) for t in runs["real"]],
            "failed_quads": failed["real"],
            "quads_per_s": args.quads * len(runs["real"]) / real_s,
        },
        "ratios": {
            "sequential_1_thread_time_over_cluster_time": round(seq1_s / local_s, 3),
            "per_round": [
                round(a / b, 3) for a, b in zip(runs["sequential"], runs["local"], strict=True)
            ],
            "sequential_1_thread_time_over_real_cluster_time": round(seq1_s / real_s, 3),
            "per_round_real_cluster": [
                round(a / b, 3) for a, b in zip(runs["sequential"], runs["real"], strict=True)
            ],
            "sequential_default_threads_time_over_cluster_time": round(
                seq2_s * len(runs["local"]) / local_s, 3
            ),
        },
        "identical_dsis": {
            "cluster_vs_sequential": identical["local"],
            "real_cluster_vs_sequential": identical["real"],
            "one_vs_two_threads": identical_threads,
        },
    }
    result["targets_met"] = {
        "cluster_1.7x_faster_than_sequential_1_thread": seq1_s >= 1.7 * local_s,
        "real_cluster_1.7x_faster_than_sequential_1_thread": seq1_s >= 1.7 * real_s,
        "identical_dsis": identical["local"] and identical["real"],
    }
    print(json.dumps(result, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
