"""Run independent pieces of numeric work on every core.

NumPy's element-wise work, SciPy's FFTs and OpenCV release the GIL on large arrays, so
plain threads run them truly in parallel: one frame, alias, row band or tile band per
thread. While such threads multiply many small matrices, OpenBLAS's own threads would
fight them for the same cores, so `single_threaded_blas` keeps OpenBLAS to one thread.
`dask_client` is the other scale: independent tasks (one quad, one burst) on a Dask
cluster of worker processes, local or remote.

NumPy does not expose a thread setting, so the OpenBLAS library NumPy loaded is found in
the process's memory map and its ``*_set_num_threads`` entry point is called through
ctypes. Without such a library (other BLAS, other OS) that is a no-op.
"""

from __future__ import annotations

import ctypes
import os
import re
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

_T = TypeVar("_T")

THREADS = min(os.cpu_count() or 1, 8)


def parallel_map(
    fn: Callable[[Any], _T], items: Sequence[Any], *, threads: int | None = None
) -> list[_T]:
    """``fn`` over ``items`` on every core (or ``threads`` of them), results in order."""
    workers = min(THREADS if threads is None else threads, len(items))
    if workers <= 1:
        return [fn(item) for item in items]
    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(fn, items))


_lock = threading.Lock()
_depth = 0
_saved = [1]


def _openblas() -> tuple[Any, Any] | None:
    maps = Path("/proc/self/maps")
    if not maps.exists():
        return None
    libs = sorted(set(re.findall(r"(/\S*openblas\S*\.so\S*)", maps.read_text())))
    for path in libs:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for prefix in ("scipy_openblas", "openblas"):
            for suffix in ("64_", ""):
                setter = getattr(lib, f"{prefix}_set_num_threads{suffix}", None)
                getter = getattr(lib, f"{prefix}_get_num_threads{suffix}", None)
                if setter is not None and getter is not None:
                    getter.restype = ctypes.c_int
                    return setter, getter
    return None


_API = _openblas()


@contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Run the body with OpenBLAS limited to one thread (re-entrant, restores on exit)."""
    global _depth
    if _API is None:
        yield
        return
    setter, getter = _API
    with _lock:
        if _depth == 0:
            _saved[0] = int(getter())
            setter(ctypes.c_int(1))
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                setter(ctypes.c_int(_saved[0]))


#: Dask settings for workers that run one large task per core: no statistical profiler
#: (it takes the GIL from the task every 10 ms for a dashboard nobody here looks at), and
#: the scheduler's, nannies' and workers' own periodic checks every second or two instead
#: of every 20-500 ms: with as many workers as cores each of those wake-ups preempts a
#: task (measured on two cores: 90-250 involuntary context switches per tile-processor
#: task instead of 10-45, and 0.81-0.88 s per task instead of 0.75-0.81 s). The local
#: cluster uses them; :func:`dask_environment` gives them to a cluster of one's own.
QUIET_WORKERS = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.worker.memory.monitor-interval": "1s",
}

#: The local cluster's: the above, and glibc's own heap thresholds in the workers (no
#: ``MALLOC_TRIM_THRESHOLD_``, see :func:`heap_reuse`).
_LOCAL_WORKERS = {
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
    **QUIET_WORKERS,
}


def dask_environment(settings: dict[str, object] = QUIET_WORKERS) -> dict[str, str]:
    """``settings`` as the environment variables Dask reads at start.

    ``distributed.admin.tick.interval`` becomes ``DASK_DISTRIBUTED__ADMIN__TICK__INTERVAL``.
    """
    return {
        "DASK_" + key.replace(".", "__").replace("-", "_").upper(): str(value)
        for key, value in settings.items()
    }


@contextmanager
def dask_client(scheduler: str | None = None, *, workers: int | None = None) -> Iterator[Any]:
    """A ``dask.distributed.Client``: of the cluster at ``scheduler``, else of a local one.

    The local cluster has ``workers`` single-threaded worker processes (default: one per
    core); it is closed on exit. Its nannies set ``OMP/MKL/OPENBLAS_NUM_THREADS=1`` (and
    more) in this process's environment for their workers, so the environment is put back
    afterwards, and processes started later from here do not inherit single-threaded BLAS.
    Its workers keep glibc's own heap thresholds (Dask's ``MALLOC_TRIM_THRESHOLD_`` is not
    set for them): a worker that runs one large task after another then reuses its heap
    like any process, instead of returning it to the system after each task and faulting
    it in again (see :func:`heap_reuse`, which covers workers of other clusters). Dask's
    statistical profiler is off in them.
    """
    try:
        import dask
        from dask.distributed import Client, LocalCluster
    except ImportError as e:  # pragma: no cover - dask[distributed] is a dependency
        raise RuntimeError(
            "a Dask cluster needs dask[distributed] (pip install 'dask[distributed]')"
        ) from e
    environ = dict(os.environ)
    cluster = None
    try:
        if scheduler:
            try:
                client = Client(scheduler, timeout="30s")
            except (OSError, ValueError) as e:
                raise OSError(
                    f"Dask scheduler {scheduler}: cannot connect ({e}); allowed: the address "
                    "of a running scheduler, e.g. tcp://host:8786"
                ) from e
        else:
            n = workers if workers is not None else (os.cpu_count() or 1)
            # the scheduler's HTTP endpoint on a free port: two local clusters may run at once
            with dask.config.set(_LOCAL_WORKERS):
                cluster = LocalCluster(
                    n_workers=n, processes=True, threads_per_worker=1, dashboard_address=":0"
                )
            client = Client(cluster)
        try:
            yield client
        finally:
            client.close()
    finally:
        if cluster is not None:
            cluster.close()
        os.environ.clear()
        os.environ.update(environ)


_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_MAX = 32 * 2**20  # glibc's largest allowed on 64-bit


def _libc() -> Any:
    try:
        lib = ctypes.CDLL("libc.so.6")
        lib.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
        lib.malloc_trim.argtypes = [ctypes.c_size_t]
        return lib
    except (OSError, AttributeError):
        return None


_LIBC = _libc()


@contextmanager
def heap_reuse() -> Iterator[None]:
    """Let glibc reuse freed heap memory for large arrays during the body.

    Dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_`` set, which also fixes
    glibc's mmap threshold at 128 KiB: then every array above it is a fresh mapping whose
    pages fault in on first touch, and chunked array code runs several times slower
    (measured: a DSI 3.5x the CPU time). The body runs with the mmap threshold at 32 MiB
    and trimming deferred; afterwards the thresholds go back to the environment's
    (or glibc's defaults) and the free memory is returned to the system. A no-op
    without glibc or when neither variable is set.
    """
    fixed = [os.environ.get(v) for v in ("MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_THRESHOLD_")]
    if _LIBC is None or not any(fixed):
        yield  # glibc's dynamic thresholds are in effect: they already reuse the heap
        return
    trim = int(fixed[0] or 128 * 1024)
    mmap = int(fixed[1] or 128 * 1024)
    _LIBC.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_MAX)
    _LIBC.mallopt(_M_TRIM_THRESHOLD, 2**30)
    try:
        yield
    finally:
        _LIBC.mallopt(_M_MMAP_THRESHOLD, mmap)
        _LIBC.mallopt(_M_TRIM_THRESHOLD, trim)
        _LIBC.malloc_trim(0)
