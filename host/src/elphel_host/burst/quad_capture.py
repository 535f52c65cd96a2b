"""Capture a quad burst: at each stage position one trigger-synchronised set of four frames.

:class:`QuadRigEngine` is the hardware (a stage and a quad camera, one set per trigger);
:func:`capture_quad_burst` moves, takes and records each set into a quad-burst directory
(``quad.json`` + burst directories ``cam0`` .. ``cam3``, read back by
:func:`elphel_host.burst.io.read_quad_burst`). Each camera's burst is written as
:mod:`elphel_host.burst.capture` writes one, so a quad capture resumes the same way, and on
any error the hardware is stopped before the error goes on.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol

from elphel_host.burst.capture import (
    CaptureResult,
    ProgressCallback,
    capture_positions,
    held_by_all,
    load_progress,
)
from elphel_host.burst.manifest import MANIFEST, VERSION, FrameEntry, Manifest, write_manifest
from elphel_host.camera.protocol import CameraInterface
from elphel_host.errors import InputFormatError
from elphel_host.fileio import write_atomic
from elphel_host.stage.positioning import MoveResult, Positioner
from elphel_host.tp.io import MANIFEST as QUAD_MANIFEST
from elphel_host.tp.io import QuadCamera, QuadManifest


@dataclass
class QuadRigEngine:
    """A stage `Positioner` and a quad camera: one trigger-synchronised set per position.

    Each set is taken as `elphel tp capture` takes one (`elphel_host.tp.capture`): the four
    ports on one common trigger, the four frames of one trigger fetched and checked.
    """

    positioner: Positioner
    camera: CameraInterface
    layout: Any = None  # elphel_host.tp.layout.QuadLayout; None = ports 0..3 on the square
    trigger_period_ms: float | None = None
    timeout_s: float = 60.0
    settle_s: float = 0.05

    def move(self, position_mm: float) -> MoveResult:
        return self.positioner.move_closed_loop(position_mm)

    def acquire_quad(self) -> tuple[list[bytes], Any]:
        """The four TIFFs (cameras 0..3) of one trigger and the set's quad manifest."""
        import tempfile

        from elphel_host.tp.capture import capture_quad

        time.sleep(self.settle_s)
        with tempfile.TemporaryDirectory(prefix="quad-set-") as tmp:
            got = capture_quad(
                self.camera,
                Path(tmp) / "set",
                layout=self.layout,
                trigger_period_ms=self.trigger_period_ms,
                timeout_s=self.timeout_s,
            )
            self.trigger_period_ms = got.trigger_period_ms  # the next sets: no fetch timed
            tiffs = [(got.path / cam.file).read_bytes() for cam in got.manifest.cameras]
        return tiffs, got.manifest

    def stop(self) -> None:
        self.positioner.client.stop()


class QuadEngine(Protocol):
    """What the quad-burst runner needs from the hardware."""

    def move(self, position_mm: float) -> MoveResult: ...

    def acquire_quad(self) -> tuple[list[bytes], Any]: ...

    def stop(self) -> None: ...


QUAD_CAMERAS = ("cam0", "cam1", "cam2", "cam3")


def capture_quad_burst(
    engine: QuadEngine,
    positions_mm: Sequence[float],
    out: str | Path,
    *,
    start_mm: float,
    top: Mapping[str, Any] | None = None,
    optics: Mapping[str, Any] | None = None,
    progress: ProgressCallback | None = None,
) -> CaptureResult:
    """Capture a quad burst: at each position one set of four frames, resumable.

    ``out`` becomes a quad-burst directory: ``cam0`` .. ``cam3`` are burst directories
    written as :class:`BurstRunner` writes one (frame file first, then the manifest entry),
    and ``quad.json`` (positions, Bayer pattern, ``optics``) appears with the first set's
    files, before their manifest entries.
    A set counts as stored when all four cameras hold it; running the capture again takes
    the sets still missing (a set that only some cameras hold is taken again).
    """
    root = Path(out)
    plan_key = {"start_mm": start_mm, "positions_mm": list(positions_mm)}
    manifests = [_camera_progress(root / name, plan_key, top) for name in QUAD_CAMERAS]
    result = CaptureResult(root, skipped=held_by_all(root, QUAD_CAMERAS, manifests))

    def take(i: int, target: float, moved: MoveResult) -> None:
        tiffs, quad = engine.acquire_quad()
        name = f"frames/{i:04d}.tif"
        for cam, data in zip(QUAD_CAMERAS, tiffs, strict=True):
            write_atomic(root / cam / name, data, sync=True)
        if not (root / QUAD_MANIFEST).exists():
            _quad_manifest(quad, optics).write(root)
        entry = FrameEntry(
            file=name, index=i, stage_mm=round(target, 6), caliper_mm=moved.caliper_mm
        )
        _record_set(root, manifests, quad, entry)

    return capture_positions(
        engine, positions_mm, start_mm, result, take, progress=progress, label="set"
    )


def _camera_progress(
    directory: Path, plan_key: dict[str, Any], top: Mapping[str, Any] | None
) -> Manifest:
    """One camera's burst so far (an empty one if none), checked to be of this plan."""
    (directory / "frames").mkdir(parents=True, exist_ok=True)
    m = load_progress(directory)
    if m is None:
        quad_camera = int(directory.name[3])
        obj = {"version": VERSION, "frames": [], **dict(top or {})}
        return Manifest.from_json({**obj, "capture": plan_key, "quad_camera": quad_camera})
    if m.extra.get("capture") != plan_key:
        raise InputFormatError(
            f"{directory / MANIFEST}: holds a burst of another plan or start position; "
            "choose a new --out or remove it"
        )
    return m


def _quad_manifest(quad: QuadManifest, optics: Mapping[str, Any] | None) -> QuadManifest:
    """The quad burst's ``quad.json``: the set's cameras (port, sensor) as ``cam0`` .. ``cam3``."""
    cameras = []
    for c, cam in enumerate(QUAD_CAMERAS):
        fields = quad.cameras[c].fields
        kept = {k: v for k, v in fields.items() if k in ("port", "sensor")}
        cameras.append(QuadCamera(file=cam, position=quad.cameras[c].position, fields=kept))
    return QuadManifest(
        cameras=tuple(cameras),
        bayer=quad.bayer,
        full_scale_dn=quad.full_scale_dn,
        optics=dict(optics) if optics else quad.optics,
    )


def _record_set(
    root: Path, manifests: list[Manifest], quad: QuadManifest, entry: FrameEntry
) -> None:
    """Enter one set in each camera's manifest (``entry`` with that camera's frame and time)."""
    for c, cam in enumerate(QUAD_CAMERAS):
        fields = quad.cameras[c].fields
        own = replace(entry, frame=fields.get("frame"), timestamp_ns=fields.get("timestamp_ns"))
        # a set only some cameras held is replaced, never entered twice
        kept = tuple(e for e in manifests[c].frames if e.index != entry.index)
        m = replace(replace(manifests[c], frames=kept).with_frame(own), bayer=quad.bayer)
        manifests[c] = m
        write_manifest(root / cam, m, sync=True)
