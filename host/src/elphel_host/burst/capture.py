"""Capture a planned burst: move the stage, let it settle, take a frame, record — resumable.

An engine knows the hardware (closed-loop stage moves, the camera's next frame); the runner
owns the order, the progress, where frames go and what happens on failure. Each frame is
written to its file first (temporary name, then rename) and then entered in the manifest
(rewritten atomically), so a crash or Ctrl-C at any moment leaves a valid burst directory
holding every frame captured so far exactly once; running the same command again captures
only the frames still missing. Ctrl-C stops the stage before it is re-raised.

With ``--fuse`` the frames also go, as they are stored, to a fusion running in the
background (:mod:`elphel_host.mfsr.stream`); the fused image is written, atomically, once
the last frame is in. A fusion failure leaves the burst as it is and exits 1.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable, Mapping
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from elphel_host.burst.io import MANIFEST, VERSION
from elphel_host.camera.client import CameraClient
from elphel_host.cli_common import add_camera_options, add_sensor_port_option
from elphel_host.errors import InputFormatError
from elphel_host.stage.positioning import MoveResult, Positioner, StageModel


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
    on_frame: Callable[[Path, Mapping[str, Any], int], None] | None = None,
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
    on_frame
        Called as ``on_frame(directory, manifest, index)`` for every frame of the burst
        once its file and manifest entry are on disk: first for the frames already present
        (resuming, in index order), then for each new one. It must return at once and not
        raise (the hardware waits); ``manifest`` changes after it returns.
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
    if on_frame is not None:
        for i in sorted(done):
            on_frame(root, manifest, i)
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
            if on_frame is not None:
                on_frame(root, manifest, i)
            if progress is not None:
                progress(len(manifest["frames"]), total, f"frame {i} at {moved.caliper_mm:.3f} mm")
    except BaseException:
        engine.stop()
        raise
    finally:
        result.seconds = time.monotonic() - t0
    return result


# -- CLI ----------------------------------------------------------------------------------------


def add_capture_parser(sub: Any) -> None:
    """Add ``elphel burst capture`` to the burst subparsers."""
    from elphel_host.stage.cli import DEFAULT_MODEL

    cp = sub.add_parser(
        "capture",
        help="move, settle, capture and record every frame of a plan (resumable)",
        description="Capture a planned burst into a burst directory (DESIGN 4.3). Each frame "
        "is saved as it arrives; running the same command again completes a partial burst. "
        "With --fuse the frames are also registered for fusion while the stage moves, and "
        "the fused image (what 'elphel mfsr OUT --scale S --method M --out FUSED' gives) is "
        "written moments after the last frame; a fusion failure keeps the frames and exits 1.",
    )
    add_camera_options(cp)
    cp.add_argument(
        "--stage", default=os.environ.get("ELPHEL_STAGE_URL"), help="stage pyserial URL"
    )
    cp.add_argument("--plan", type=Path, required=True, help="plan JSON (elphel burst plan --out)")
    cp.add_argument("--out", type=Path, required=True, help="burst directory to write")
    add_sensor_port_option(cp, help="sensor port of the camera (default 0)")
    cp.add_argument("--start-mm", type=float, help="plan origin on the stage (default: here)")
    cp.add_argument("--model", type=Path, default=DEFAULT_MODEL, help="stage calibration file")
    cp.add_argument("--settle-s", type=float, default=0.05, help="wait after each move")
    cp.add_argument("--focal-length-mm", type=float, help="record optics in the manifest")
    cp.add_argument("--pixel-pitch-um", type=float)
    cp.add_argument("--distance-mm", type=float)
    cp.add_argument("--json", action="store_true", help="print one JSON object")
    fz = cp.add_argument_group("fusion while capturing (elphel mfsr on the finished burst)")
    fz.add_argument(
        "--fuse",
        action="store_true",
        help="register each frame as it arrives and write the fused image at the end",
    )
    fz.add_argument(
        "--scale", type=int, metavar="S", help="up-sampling factor 1..8 (default: the plan's)"
    )
    fz.add_argument(
        "--method",
        choices=("robust", "baseline"),
        help="as elphel mfsr --method (default robust)",
    )
    fz.add_argument(
        "--fused-out",
        type=Path,
        metavar="FUSED.tif",
        help="fused TIFF, 16-bit DN, with a PNG preview next to it (default OUT/fused.tif)",
    )
    cp.set_defaults(func=run_capture, parser=cp)


def _fuse_options(
    args: argparse.Namespace, plan: Mapping[str, Any]
) -> tuple[int, str, Path] | None:
    """(scale, method, fused TIFF) for --fuse, or None; wrong combinations are usage errors."""
    parser: argparse.ArgumentParser = args.parser
    if not args.fuse:
        extra = [
            option
            for option, value in (
                ("--scale", args.scale),
                ("--method", args.method),
                ("--fused-out", args.fused_out),
            )
            if value is not None
        ]
        if extra:
            parser.error(f"{', '.join(extra)}: allowed only with --fuse")
        return None
    scale = args.scale if args.scale is not None else plan.get("scale")
    if isinstance(scale, bool) or not isinstance(scale, int) or not 1 <= scale <= 8:
        source = "--scale" if args.scale is not None else f"the plan {args.plan}"
        parser.error(f"--fuse: scale={scale!r} from {source}; allowed: an integer 1..8")
    out = args.fused_out if args.fused_out is not None else args.out / "fused.tif"
    return scale, args.method or "robust", out


def run_capture(args: argparse.Namespace) -> int:
    from elphel_host.cli_common import emit
    from elphel_host.stage.client import StageClient

    if not args.camera or not args.stage:
        args.parser.error("give --camera and --stage (or ELPHEL_CAMERA_URL / ELPHEL_STAGE_URL)")
    try:
        plan = json.loads(args.plan.read_text())
        positions = [float(p) for p in plan["positions_mm"]]
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
        raise InputFormatError(f"{args.plan}: not a burst plan ({e})") from e
    fuse = _fuse_options(args, plan)
    if fuse is not None:  # an output that cannot be written fails before the rig moves
        fuse[2].parent.mkdir(parents=True, exist_ok=True)
    top: dict[str, Any] = {"plan": {k: plan[k] for k in ("scale", "tilt_deg") if k in plan}}
    optics = {
        "focal_length_mm": args.focal_length_mm,
        "pixel_pitch_um": args.pixel_pitch_um,
        "object_distance_mm": args.distance_mm,
    }
    if all(v is not None for v in optics.values()):
        top["optics"] = optics
    with ExitStack() as stack:
        stream = None
        if fuse is not None:
            # imported here: plain captures do not load OpenCV and SciPy
            from elphel_host.mfsr.stream import FusionStream

            stream = stack.enter_context(
                FusionStream(frames=len(positions), scale=fuse[0], method=fuse[1])
            )
        with StageClient(args.stage) as stage, CameraClient(args.camera, args.token) as camera:
            positioner = Positioner(stage, StageModel.load(args.model))
            progress_so_far = load_progress(args.out)
            if progress_so_far is not None:
                start_mm = float(progress_so_far["capture"]["start_mm"])
            elif args.start_mm is not None:
                start_mm = args.start_mm
            else:
                start_mm = round(positioner.read_mm(), 2)
            top["stage"] = {"mm_per_step": positioner.model.mm_per_step}
            if "tilt_deg" in plan:
                top["stage"]["axis_angle_deg"] = float(plan["tilt_deg"])
            engine = RigEngine(positioner, camera, port=args.sensor_port, settle_s=args.settle_s)

            def progress(done: int, total: int, message: str) -> None:
                fusion = "" if stream is None else f"; fusion: {stream.status()}"
                print(f"burst: {done}/{total} {message}{fusion}", file=sys.stderr, flush=True)

            result = capture_burst(
                engine,
                positions,
                args.out,
                start_mm=start_mm,
                top=top,
                progress=progress,
                on_frame=None if stream is None else stream.frame_stored,
            )
        summary: dict[str, Any] = {
            "out": str(result.directory),
            "captured": result.captured,
            "already_present": result.skipped,
            "frames": len(positions),
            "start_mm": start_mm,
            "seconds": round(result.seconds, 2),
        }
        human = [
            f"{result.directory}: {len(result.captured)} frames captured, "
            f"{len(result.skipped)} already there, in {result.seconds:.1f} s"
        ]
        error = None
        if stream is not None and fuse is not None:
            from elphel_host.errors import FusionError
            from elphel_host.mfsr.stream import finish_and_write

            def say(message: str) -> None:
                print(f"fusion: {message}", file=sys.stderr, flush=True)

            try:
                fused = finish_and_write(stream, fuse[2], burst=result.directory, progress=say)
            except FusionError as e:
                error = str(e)
                fused = {"error": error}
                human.append(error)
            else:
                excluded = "; ".join(f"{e['index']}: {e['reason']}" for e in fused["excluded"])
                human.append(
                    f"{fused['out']}: {fused['method']} x{fuse[0]}, {fused['used']}/"
                    f"{fused['frames']} frames, written {fused['after_capture_s']:.2f} s "
                    "after the last frame" + (f"; excluded {excluded}" if excluded else "")
                )
            summary["fusion"] = fused
    emit(args, summary, "\n".join(human))
    if error is not None:
        print(f"elphel: {error}", file=sys.stderr)
        return 1
    return 0
