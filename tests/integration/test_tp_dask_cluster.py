"""`elphel tp QUAD_DIR... --out-dir DIR --scheduler ADDRESS` on a real Dask cluster.

The test starts `dask scheduler` and two `dask worker` processes on 127.0.0.1 (each
worker one process, one thread), runs a small sequence through them and checks every DSI
bit for bit against the single-quad command in this process. The processes are bounded
in time and killed afterwards.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from elphel_host.cli import main
from elphel_host.tp import dsi
from elphel_sim import quad as simquad

DASK = Path(sys.executable).with_name("dask")
START_TIMEOUT_S = 90.0


def _stop(procs: list[subprocess.Popen[bytes]]) -> None:
    for p in procs:
        if p.poll() is None:
            p.terminate()
    deadline = time.monotonic() + 10
    for p in procs:
        try:
            p.wait(timeout=max(deadline - time.monotonic(), 0.1))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=10)


@pytest.fixture()
def cluster(tmp_path: Path) -> Iterator[str]:
    """A scheduler and two single-threaded workers on loopback; yields the address."""
    if not DASK.exists():
        pytest.fail(f"{DASK} missing: dask[distributed] is a dependency of elphel-host")
    sched_file = tmp_path / "scheduler.json"
    env = {**os.environ, "DASK_DISTRIBUTED__WORKER__DAEMON": "False"}
    procs: list[subprocess.Popen[bytes]] = []
    log = (tmp_path / "dask.log").open("wb")
    try:
        procs.append(
            subprocess.Popen(
                [
                    str(DASK),
                    "scheduler",
                    "--host",
                    "127.0.0.1",
                    "--port",
                    "0",
                    "--no-dashboard",
                    "--scheduler-file",
                    str(sched_file),
                ],
                stdout=log,
                stderr=subprocess.STDOUT,
                env=env,
            )
        )
        deadline = time.monotonic() + START_TIMEOUT_S
        while not sched_file.is_file():
            assert procs[0].poll() is None, "dask scheduler exited"
            assert time.monotonic() < deadline, "dask scheduler did not start"
            time.sleep(0.2)
        address = json.loads(sched_file.read_text())["address"]
        for _ in range(2):
            procs.append(
                subprocess.Popen(
                    [
                        str(DASK),
                        "worker",
                        address,
                        "--host",
                        "127.0.0.1",
                        "--nthreads",
                        "1",
                        "--nworkers",
                        "1",
                        "--no-dashboard",
                        "--no-nanny",
                    ],
                    stdout=log,
                    stderr=subprocess.STDOUT,
                    env=env,
                )
            )
        from dask.distributed import Client

        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=START_TIMEOUT_S)
            assert len(client.scheduler_info()["workers"]) == 2
        yield address
    finally:
        _stop(procs)
        log.close()


def test_sequence_on_a_real_cluster(
    cluster: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    quads = tmp_path / "quads"
    rig = simquad.QuadRig(width=160, height=96)
    for i in range(4):
        simquad.simulate_quad_dir(quads / f"frame{i:03d}", rig, seed=20 + i)
    out = tmp_path / "dsi"
    rc = main(["tp", str(quads), "--out-dir", str(out), "--scheduler", cluster, "--json"])
    got = json.loads(capsys.readouterr().out)
    assert rc == 0, got
    assert got["scheduler"] == cluster
    assert [r["status"] for r in got["quads"]] == ["done"] * 4
    for i in range(4):
        name = f"frame{i:03d}"
        assert main(["tp", str(quads / name), "--out", str(tmp_path / "one.tif")]) == 0
        want = dsi.read_dsi(tmp_path / "one.tif")[0]
        layers = dsi.read_dsi(out / f"{name}.tif")[0]
        assert list(layers) == list(want)
        for k in want:
            assert np.array_equal(layers[k], want[k], equal_nan=True), (name, k)
    # the two worker processes ran the tasks, not this process
    from dask.distributed import Client

    with Client(cluster, timeout="30s") as client:
        workers = set(client.scheduler_info()["workers"])
    assert {r["worker"] for r in got["quads"]} == workers
