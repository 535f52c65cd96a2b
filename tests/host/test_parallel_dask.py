"""The Dask settings the tile processor's sequences run with (`elphel_host.parallel`)."""

from __future__ import annotations

import os
from typing import Any

import dask

from elphel_host.parallel import QUIET_WORKERS, dask_client, dask_environment


def test_the_environment_gives_dask_the_quiet_settings() -> None:
    env = dask_environment()
    assert all(k.startswith("DASK_DISTRIBUTED__") for k in env)
    collected = dask.config.collect_env(env)
    for key, value in QUIET_WORKERS.items():
        assert dask.config.get(key, config=collected) == value, key


def _worker_settings() -> dict[str, Any]:
    import dask as worker_dask

    return {
        "config": {k: worker_dask.config.get(k) for k in QUIET_WORKERS},
        "malloc_trim": os.environ.get("MALLOC_TRIM_THRESHOLD_"),
        "omp": os.environ.get("OMP_NUM_THREADS"),
    }


def test_local_cluster_workers_run_quiet_and_keep_glibc_heap() -> None:
    before = dict(os.environ)
    with dask_client(workers=1) as client:
        (got,) = client.run(_worker_settings).values()
    assert got["config"] == QUIET_WORKERS
    assert got["malloc_trim"] is None
    assert got["omp"] == "1"  # the nanny's single-threaded BLAS stays
    assert dict(os.environ) == before  # and this process's environment is put back
