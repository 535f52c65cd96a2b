"""Capture one burst per camera: at each stage position, every camera's next frame together.

A rig of several cameras on one carriage (the dissertation's two Raspberry Pis, each with
its own elphel-camd) takes a burst per camera at the same stage positions.
:class:`MultiCameraEngine` is the hardware (the stage and the cameras; the frames of a
position are asked for at the same moment, one thread per camera);
:func:`capture_multi_burst` moves, takes and records them into ``OUT/cam0``,
``OUT/cam1``, ... (camera i of the command line), each a burst directory written as
:mod:`elphel_host.burst.capture` writes one: frame file first, then the manifest entry.
A position counts as stored once every camera holds it; running the capture again takes
the positions still missing. On any error the hardware is stopped before the error goes
on.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
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

Acquired = tuple[bytes, dict[str, Any]]


def camera_directory(index: int) -> str:
    """The burst directory of camera ``index`` (its place on the command line)."""
    return f"cam{index}"


@dataclass
class MultiCameraEngine:
    """A stage `Positioner` and several cameras, each read at the same sensor port."""

    positioner: Positioner
    cameras: Sequence[CameraInterface]
    port: int = 0
    settle_s: float = 0.05

    def move(self, position_mm: float) -> MoveResult:
        return self.positioner.move_closed_loop(position_mm)

    def acquire_all(self) -> list[Acquired]:
        """Every camera's next frame (TIFF bytes, metadata), asked for at once."""
        time.sleep(self.settle_s)

        def take(camera: CameraInterface) -> Acquired:
            frame = camera.capture(self.port)
            return frame.tiff, frame.metadata

        with ThreadPoolExecutor(max_workers=len(self.cameras)) as pool:
            return list(pool.map(take, self.cameras))

    def stop(self) -> None:
        self.positioner.client.stop()


class MultiEngine(Protocol):
    """What the multi-camera runner needs from the hardware."""

    cameras: Sequence[Any]

    def move(self, position_mm: float) -> MoveResult: ...

    def acquire_all(self) -> list[Acquired]: ...

    def stop(self) -> None: ...


def capture_multi_burst(
    engine: MultiEngine,
    positions_mm: Sequence[float],
    out: str | Path,
    *,
    start_mm: float,
    top: Mapping[str, Any] | None = None,
    progress: ProgressCallback | None = None,
) -> CaptureResult:
    """Capture a burst per camera at the same positions, resumable.

    ``out`` holds one burst directory per camera (`camera_directory`); ``top`` gives
    their manifests' extra top-level fields (``optics``, ``stage``, ``plan``).
    """
    root = Path(out)
    plan_key = {"start_mm": start_mm, "positions_mm": list(positions_mm)}
    names = [camera_directory(i) for i in range(len(engine.cameras))]
    manifests = [_camera_progress(root / name, i, plan_key, top) for i, name in enumerate(names)]
    result = CaptureResult(root, skipped=held_by_all(root, names, manifests))

    def take(i: int, target: float, moved: MoveResult) -> None:
        frames = engine.acquire_all()
        entry = FrameEntry(
            file=f"frames/{i:04d}.tif",
            index=i,
            stage_mm=round(target, 6),
            caliper_mm=moved.caliper_mm,
        )
        for c, (name, (tiff, meta)) in enumerate(zip(names, frames, strict=True)):
            manifests[c] = _record(root / name, manifests[c], entry, tiff, meta)

    return capture_positions(engine, positions_mm, start_mm, result, take, progress=progress)


def _camera_progress(
    directory: Path, camera: int, plan_key: dict[str, Any], top: Mapping[str, Any] | None
) -> Manifest:
    """One camera's burst so far (an empty one if none), checked to be of this plan."""
    (directory / "frames").mkdir(parents=True, exist_ok=True)
    m = load_progress(directory)
    if m is None:
        obj = {"version": VERSION, "frames": [], **dict(top or {})}
        return Manifest.from_json({**obj, "capture": plan_key, "rig_camera": camera})
    if m.extra.get("capture") != plan_key:
        raise InputFormatError(
            f"{directory / MANIFEST}: holds a burst of another plan or start position; "
            "choose a new --out or remove it"
        )
    return m


def _record(
    directory: Path, manifest: Manifest, entry: FrameEntry, tiff: bytes, meta: Mapping[str, Any]
) -> Manifest:
    """Write one camera's frame, then enter it in its manifest (replacing a partial one)."""
    write_atomic(directory / entry.file, tiff, sync=True)
    own = replace(entry, frame=meta.get("frame"), timestamp_ns=meta.get("timestamp_ns"))
    kept = tuple(e for e in manifest.frames if e.index != entry.index)
    m = replace(manifest, frames=kept).with_frame(own)
    if m.bayer is None and "bayer" in meta:
        m = replace(m, bayer=meta["bayer"])
    write_manifest(directory, m, sync=True)
    return m
