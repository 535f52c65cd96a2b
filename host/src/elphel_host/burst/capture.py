"""Capture a planned burst: move the stage, let it settle, take a frame, record — resumable.

An engine knows the hardware (closed-loop stage moves, the camera's next frame); the runner
owns the order, the progress, where frames go and what happens on failure. Each frame is
written to its file first (temporary name, then rename) and then entered in the manifest
(rewritten atomically), so a crash or Ctrl-C at any moment leaves a valid burst directory
holding every frame captured so far exactly once; running the same command again captures
only the frames still missing. Ctrl-C stops the stage before it is re-raised.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from elphel_host.burst.io import MANIFEST, VERSION
from elphel_host.camera.client import CameraClient
from elphel_host.errors import InputFormatError
from elphel_host.stage.positioning import MoveResult, Positioner


class Engine(Protocol):
    """What the runner needs from the hardware."""

    def move(self, position_mm: float) -> MoveResult:
        """Move the carriage to an absolute position, verified by the caliper."""
        ...

    def acquire(self) -> tuple[bytes, dict[str, Any]]:
        """The next frame (TIFF bytes) and its metadata, taken with the carriage at rest."""
        ...

    def stop(self) -> None:
        """Stop the hardware at once (called on errors and Ctrl-C)."""
        ...


@dataclass
class RigEngine:
    """The real rig: a stage `Positioner` and a camera daemon port."""

    positioner: Positioner
    camera: CameraClient
    port: int = 0
    settle_s: float = 0.05

    def move(self, position_mm: float) -> MoveResult:
        return self.positioner.move_closed_loop(position_mm)

    def acquire(self) -> tuple[bytes, dict[str, Any]]:
        time.sleep(self.settle_s)
        frame = self.camera.capture(self.port)
        return frame.tiff, frame.metadata

    def stop(self) -> None:
        self.positioner.client.stop()


@dataclass
class CaptureResult:
    directory: Path
    captured: list[int] = field(default_factory=list)
    skipped: list[int] = field(default_factory=list)
    seconds: float = 0.0


def _atomic_write(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".part")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def load_progress(out: Path) -> dict[str, Any] | None:
    """The manifest of a partly captured burst, or None if there is none yet."""
    path = out / MANIFEST
    if not path.exists():
        return None
    try:
        manifest = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise InputFormatError(f"{path}: not valid JSON ({e}); move it away to start over") from e
    if manifest.get("version") != VERSION or not isinstance(manifest.get("frames"), list):
        raise InputFormatError(f"{path}: not a version-{VERSION} burst manifest")
    return manifest


def capture_burst(
    engine: Engine,
    positions_mm: list[float],
    out: str | Path,
    *,
    start_mm: float,
    top: Mapping[str, Any] | None = None,
    progress: Callable[[int, int, str], None] | None = None,
) -> CaptureResult:
    """Capture one frame at each stage position into a burst directory.

    Parameters
    ----------
    engine
        The hardware.
    positions_mm
        Positions relative to ``start_mm`` (a plan's ``positions_mm``).
    out
        Burst directory; if it holds a partial burst of the same plan, it is completed.
    start_mm
        Absolute stage position of the plan's origin (kept in the manifest for resuming).
    top
        Extra top-level manifest fields (``optics``, ``stage``, ``bayer``...).
    progress
        Called as ``progress(done, total, message)`` after each step.
    """
    root = Path(out)
    (root / "frames").mkdir(parents=True, exist_ok=True)
    manifest = load_progress(root)
    plan_key = {"start_mm": start_mm, "positions_mm": list(positions_mm)}
    if manifest is None:
        manifest = {"version": VERSION, "frames": [], **dict(top or {}), "capture": plan_key}
    elif manifest.get("capture") != plan_key:
        raise InputFormatError(
            f"{root / MANIFEST}: holds a burst of another plan or start position; "
            "choose a new --out or remove it"
        )
    done = {int(e["index"]) for e in manifest["frames"] if (root / e["file"]).exists()}
    manifest["frames"] = [e for e in manifest["frames"] if int(e["index"]) in done]
    result = CaptureResult(root, skipped=sorted(done))
    t0 = time.monotonic()
    total = len(positions_mm)
    try:
        for i, rel in enumerate(positions_mm):
            if i in done:
                continue
            target = start_mm + rel
            moved = engine.move(target)
            tiff, meta = engine.acquire()
            name = f"frames/{i:04d}.tif"
            _atomic_write(root / name, tiff)
            entry = {
                "file": name,
                "index": i,
                "stage_mm": round(target, 6),
                "caliper_mm": moved.caliper_mm,
                "frame": meta.get("frame"),
                "timestamp_ns": meta.get("timestamp_ns"),
            }
            manifest["frames"].append(entry)
            manifest["frames"].sort(key=lambda e: e["index"])
            if "bayer" not in manifest:
                manifest["bayer"] = meta.get("bayer")
            _atomic_write(
                root / MANIFEST, (json.dumps(manifest, indent=1, sort_keys=True) + "\n").encode()
            )
            result.captured.append(i)
            if progress is not None:
                progress(len(manifest["frames"]), total, f"frame {i} at {moved.caliper_mm:.3f} mm")
    except BaseException:
        engine.stop()
        raise
    finally:
        result.seconds = time.monotonic() - t0
    return result
