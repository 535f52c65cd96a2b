"""A sequence of quads, the extrinsics refined on the fly: ``elphel tp ... --refine-extrinsics``.

The quads run one after the other, in order, in this process: each quad's DSI is computed
with the calibration as refined by the quads before it (the first quad's own calibration
to start with), written to ``DIR/<quad name>.tif``, and then refines the calibration for
the next quads (:class:`~elphel_host.calibrate.field_running.RunningField`). At the end
the refined calibration is written as ``DIR/calibration.json`` (the starting document
with cameras 1-3's ``fx``, ``fy``, ``R`` and ``t_mm`` updated and a ``field`` entry) and
``DIR/camN.yml``. DSIs already in ``DIR`` are computed again: each depends on the quads
before it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from elphel_host.calibrate.field import CORRECTIONS, pixels_per_unit
from elphel_host.calibrate.field_running import QuadUpdate, RunningField
from elphel_host.calibrate.result import finite_json, read_cameras, write_updated_cameras
from elphel_host.errors import InputFormatError
from elphel_host.tp.calibrated import calibration_file
from elphel_host.tp.config import TpConfig
from elphel_host.tp.io import read_quad_dir
from elphel_host.tp.sequence import QuadJob, quad_dsi


@dataclass(frozen=True)
class RefinedSequence:
    """What :func:`run_refining` did: per quad its result, the refined calibration's file."""

    results: list[dict[str, Any]]
    calibration: Path
    corrections: list[dict[str, float]]


def starting_calibration(job: QuadJob) -> Path:
    """The calibration.json the first quad's quad.json names (where the refinement starts).

    Raises
    ------
    InputFormatError
        The quad has no calibration.
    """
    qs = read_quad_dir(job.quad_dir)
    if qs.manifest.calibration is None:
        raise InputFormatError(
            f"{job.quad_dir}: quad.json names no calibration; allowed with "
            "--refine-extrinsics: quads of a calibrated quad (`elphel tp capture "
            "--calibration CALIB_DIR`, or a 'calibration' entry in quad.json)"
        )
    return calibration_file(Path(job.quad_dir) / qs.manifest.calibration)


def update_json(update: QuadUpdate) -> dict[str, Any]:
    """A quad's refinement figures: mismatch before and after (RMS over the cameras, and each)."""

    def rms(v: np.ndarray) -> float:
        return float(np.sqrt(np.mean(v**2)))

    return finite_json(
        {
            "updated": update.updated,
            "mismatch_before_px": rms(update.mismatch_before_px),
            "mismatch_after_px": rms(update.mismatch_after_px),
            "cameras": [
                {"mismatch_before_px": float(b), "mismatch_after_px": float(a)}
                for b, a in zip(update.mismatch_before_px, update.mismatch_after_px, strict=True)
            ],
            "tiles": update.tiles,
            "infinity_tiles": update.infinity_tiles,
            "search_px": update.search_px,
        }
    )


def corrections_json(running: RunningField) -> list[dict[str, float]]:
    """Per camera the corrections applied: mrad, ppm, and pixels (as `elphel calibrate field`)."""
    out = []
    for (lens, _, _), corr in zip(running.cameras, running.corrections, strict=True):
        px = corr * pixels_per_unit(lens)
        entry = {f"{k}_mrad": float(v) * 1e3 for k, v in zip(CORRECTIONS[:3], corr, strict=False)}
        entry["zoom_ppm"] = float(corr[3]) * 1e6
        entry.update({f"{k}_px": float(v) for k, v in zip(CORRECTIONS, px, strict=True)})
        out.append(entry)
    return out


def _one_quad(job: QuadJob, running: RunningField, config: TpConfig) -> dict[str, Any]:
    qs = read_quad_dir(job.quad_dir)
    placed = running.place(qs.quad)
    Path(job.out).parent.mkdir(parents=True, exist_ok=True)
    dsi, got = quad_dsi(replace(qs, quad=placed), job.out, config)
    update = running.update(placed, dsi["disparity"])
    return {"quad": job.quad_dir, "status": "done", **got, "refinement": update_json(update)}


def run_refining(
    jobs: Sequence[QuadJob],
    out_dir: str | Path,
    config: TpConfig,
    *,
    memory: float = 0.5,
    on_result: Callable[[dict[str, Any], int, int], None] | None = None,
) -> RefinedSequence:
    """Run ``jobs`` in order, refining the extrinsics on the fly (module docstring).

    A quad that fails is reported with its error (``status`` ``"failed"``) and leaves the
    calibration as it was. ``on_result(result, done, total)`` is called after each quad.

    Raises
    ------
    InputFormatError
        No jobs, or a first quad without a calibration.
    """
    if not jobs:
        raise InputFormatError("no quad directories; allowed: one or more")
    source = starting_calibration(jobs[0])
    running = RunningField(read_cameras(source), memory=memory, config=config)
    results: list[dict[str, Any]] = []
    for job in jobs:
        try:
            res = _one_quad(job, running, config)
        except (InputFormatError, OSError, ValueError) as e:
            res = {"quad": job.quad_dir, "dsi": job.out, "status": "failed", "error": str(e)}
        results.append(res)
        if on_result is not None:
            on_result(res, len(results), len(jobs))
    corrections = corrections_json(running)
    field = {
        "quads": [r["quad"] for r in results if r["status"] == "done"],
        "corrections": corrections,
    }
    path = write_updated_cameras(
        source, list(running.cameras), out_dir, extra={"field": finite_json(field)}
    )
    return RefinedSequence(results, path, corrections)
