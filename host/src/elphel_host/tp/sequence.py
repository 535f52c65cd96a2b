"""Many quad directories, one DSI each: ``elphel tp QUAD_DIR... --out-dir DIR``.

A recorded sequence is thousands of independent quads, so they run as independent
tasks, one quad per task, on a Dask cluster (a local one by default, or an existing one
given by its scheduler address). Each task reads its quad directory, computes the DSI
exactly as the single-quad command does (the same :func:`quad_dsi`, so the layers are
bit for bit the same) and writes ``DIR/<quad name>.tif`` through a temporary name. A quad
that fails is reported with its error and the others go on; a DSI already in ``DIR`` is
not computed again, so an interrupted run is resumed by running it again.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elphel_host.errors import InputFormatError
from elphel_host.parallel import heap_reuse
from elphel_host.tp.calibrated import CalibratedGeometry
from elphel_host.tp.config import TpConfig
from elphel_host.tp.dsi import write_dsi
from elphel_host.tp.io import MANIFEST, QuadSet, read_quad_dir
from elphel_host.tp.processor import disparity_map
from elphel_host.tp.tile_pass import load_kernels


@dataclass(frozen=True)
class QuadJob:
    """One quad directory and the DSI it becomes."""

    quad_dir: str
    out: str

    @property
    def name(self) -> str:
        return Path(self.out).stem


def find_quads(paths: Sequence[str | Path]) -> list[Path]:
    """Quad directories named by ``paths``: each a quad directory or a directory of them.

    A directory without ``quad.json`` stands for its subdirectories that have one, in
    name order.
    """
    found: list[Path] = []
    for raw in paths:
        path = Path(raw)
        if not path.is_dir():
            raise InputFormatError(
                f"{path}: not a directory; allowed: a quad directory "
                f"({MANIFEST} + cam0..3.tif) or a directory of them"
            )
        if (path / MANIFEST).is_file():
            found.append(path)
            continue
        subs = sorted(p for p in path.iterdir() if (p / MANIFEST).is_file())
        if not subs:
            raise InputFormatError(
                f"{path}: no {MANIFEST} in it or in any subdirectory; allowed: a quad "
                "directory or a directory of quad directories"
            )
        found.extend(subs)
    return found


def plan_jobs(quads: Sequence[Path], out_dir: str | Path) -> list[QuadJob]:
    """One job per quad, ``out_dir/<quad name>.tif``; quad names must be distinct."""
    names = [q.resolve().name for q in quads]
    seen: dict[str, Path] = {}
    for name, q in zip(names, quads, strict=True):
        if name in seen:
            raise InputFormatError(
                f"quad directories {seen[name]} and {q} share the name {name!r}; allowed: "
                "distinct names (each becomes <name>.tif in --out-dir)"
            )
        seen[name] = q
    return [
        QuadJob(quad_dir=str(q), out=str(Path(out_dir) / f"{n}.tif"))
        for q, n in zip(quads, names, strict=True)
    ]


def quad_dsi(
    qs: QuadSet, out: str | Path, config: TpConfig
) -> tuple[dict[str, NDArray[np.float32]], dict[str, Any]]:
    """Compute a quad set's DSI and write it to ``out``; its layers and a summary.

    ``seconds`` is the DSI's time; the compiled kernels are loaded before it starts.
    """
    load_kernels()
    t0 = time.perf_counter()
    dsi = disparity_map(qs.quad, config=config)
    seconds = time.perf_counter() - t0
    h, w = qs.quad.images.shape[1:]
    write_dsi(
        out,
        dsi,
        image_size=(w, h),
        geometry=qs.quad.geometry,
        bayer=qs.quad.bayer,
        extra={
            "fatZero": config.fat_zero,
            "refinePasses": config.refine_passes,
            **calibration_properties(qs),
        },
    )
    return dsi, {
        "dsi": str(out),
        "tiles_x": int(dsi["disparity"].shape[1]),
        "tiles_y": int(dsi["disparity"].shape[0]),
        "layers": list(dsi),
        "seconds": round(seconds, 3),
        "disparity_median": float(np.nanmedian(dsi["disparity"])),
        "strength_median": float(np.nanmedian(dsi["strength"])),
    }


def calibration_properties(qs: QuadSet) -> dict[str, Any]:
    """The DSI's record of a calibrated quad's geometry (none for an ideal one)."""
    cal = qs.quad.geometry.calibration
    if not isinstance(cal, CalibratedGeometry):
        return {}
    return {
        "calibration": qs.manifest.calibration,
        "virtualCamera": "pinhole at the cameras' centre, camera 0's axes, centre W/2, H/2",
        "focalLengthPx": cal.focal_px,
        "baselineMm": cal.baseline_mm,
    }


def dsi_of_quad(quad_dir: str | Path, out: str | Path, config: TpConfig) -> dict[str, Any]:
    """Read a quad directory, compute its DSI, write it to ``out``; a summary."""
    return quad_dsi(read_quad_dir(quad_dir), out, config)[1]


def run_job(job: QuadJob, config: TpConfig) -> dict[str, Any]:
    """One task: the DSI of one quad, or the error that stopped it (never raises)."""
    try:
        Path(job.out).parent.mkdir(parents=True, exist_ok=True)
        with heap_reuse():  # a Dask worker's malloc settings would slow it down 3.5x
            got = dsi_of_quad(job.quad_dir, job.out, config)
    except Exception as e:
        return {"quad": job.quad_dir, "dsi": job.out, "status": "failed", "error": _error(e)}
    return {"quad": job.quad_dir, "status": "done", "worker": _worker(), **got}


def _worker() -> str | None:
    """Address of the Dask worker running this task (None outside a worker)."""
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except (ImportError, ValueError):
        return None


def _error(e: BaseException) -> str:
    return f"{type(e).__name__}: {e}"


def run_sequence(
    jobs: Sequence[QuadJob],
    config: TpConfig,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    on_result: Callable[[dict[str, Any], int, int], None] | None = None,
) -> list[dict[str, Any]]:
    """Run ``jobs`` on a Dask cluster, one task per quad; results in job order.

    Jobs whose DSI exists already are not submitted (``status`` ``"skipped"``).
    ``scheduler``: address of an existing cluster, else a local one of ``workers``
    single-threaded worker processes (default: one per core). Each task runs the tile
    processor with ``config`` (``config.threads`` threads; 1 suits one task per core).
    ``on_result(result, done, total)`` is called as each quad finishes (skipped ones
    first).
    """
    from elphel_host.parallel import dask_client

    results: list[dict[str, Any] | None] = [None] * len(jobs)
    todo: list[int] = []
    total = len(jobs)
    done = 0
    for i, job in enumerate(jobs):
        if Path(job.out).is_file():
            results[i] = {"quad": job.quad_dir, "dsi": job.out, "status": "skipped"}
            done += 1
            if on_result is not None:
                on_result(results[i], done, total)  # type: ignore[arg-type]
        else:
            todo.append(i)
    if todo:
        with dask_client(scheduler, workers=workers) as client:
            from dask.distributed import as_completed

            futures = {
                client.submit(run_job, jobs[i], config, pure=False, key=f"tp-{i}-{jobs[i].name}"): i
                for i in todo
            }
            for future in as_completed(futures):
                i = futures[future]
                try:
                    res = future.result()
                except Exception as e:
                    res = {
                        "quad": jobs[i].quad_dir,
                        "dsi": jobs[i].out,
                        "status": "failed",
                        "error": _error(e),
                    }
                results[i] = res
                done += 1
                if on_result is not None:
                    on_result(res, done, total)
    return [r for r in results if r is not None]
