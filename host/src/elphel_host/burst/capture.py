"""Capture a planned burst: move the stage, let it settle, take a frame, record — resumable.

An engine knows the hardware (closed-loop stage moves, the camera's next frame, stopping);
the runner (:class:`BurstRunner`) owns the order, the progress, cancelling, resuming, where
frames go and what happens on failure. Each frame is written to its file first (temporary
name, then rename) and then entered in the manifest (rewritten atomically through
:mod:`elphel_host.burst.manifest`), so a crash or Ctrl-C at any moment leaves a valid burst
directory holding every frame captured so far exactly once; running the same capture again
takes only the frames still missing. On any error, and on Ctrl-C, the hardware is stopped
before the error goes on.

:meth:`BurstRunner.start` runs a capture in the background and returns its handle
(:class:`CaptureStatus`: ``progress``, ``done``, ``cancel()``, ``wait(timeout)``, callbacks);
:meth:`BurstRunner.run`, or :func:`capture_burst`, blocks instead. Quad bursts (a set of
four frames at each position) are captured by :mod:`elphel_host.burst.quad_capture`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

from elphel_host.burst.manifest import (
    MANIFEST,
    VERSION,
    FrameEntry,
    Manifest,
    read_manifest,
    write_manifest,
)
from elphel_host.camera.protocol import CameraInterface
from elphel_host.errors import CaptureTimeout, InputFormatError
from elphel_host.fileio import write_atomic
from elphel_host.stage.positioning import MoveResult, Positioner

ProgressCallback = Callable[[int, int, str], None]
FrameCallback = Callable[[Path, Manifest, int], None]


class Engine(Protocol):
    """What the runner needs from the hardware."""

    def move(self, position_mm: float) -> MoveResult:
        """Move the carriage to an absolute position, verified by the caliper."""
        ...

    def acquire(self) -> tuple[bytes, dict[str, Any]]:
        """The next frame (TIFF bytes) and its metadata, taken with the carriage at rest."""
        ...

    def stop(self) -> None:
        """Stop the hardware at once (called on errors, cancel and Ctrl-C)."""
        ...


@dataclass
class RigEngine:
    """The real rig: a stage `Positioner` and a camera daemon's sensor port."""

    positioner: Positioner
    camera: CameraInterface
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
    """What a capture did: frames captured now, frames found already there, wall time."""

    directory: Path
    captured: list[int] = field(default_factory=list)
    skipped: list[int] = field(default_factory=list)
    seconds: float = 0.0
    cancelled: bool = False


def held_by_all(root: Path, names: Sequence[str], manifests: Sequence[Manifest]) -> list[int]:
    """Positions whose frame every camera directory ``root/name`` already holds on disk."""
    held = [
        {e.index for e in m.frames if e.index is not None and (root / name / e.file).exists()}
        for m, name in zip(manifests, names, strict=True)
    ]
    return sorted(set.intersection(*held))


class Mover(Protocol):
    """What `capture_positions` needs of an engine: moves, and a stop after an error."""

    def move(self, target_mm: float) -> MoveResult: ...

    def stop(self) -> None: ...


def capture_positions(
    engine: Mover,
    positions_mm: Sequence[float],
    start_mm: float,
    result: CaptureResult,
    take: Callable[[int, float, MoveResult], None],
    *,
    progress: ProgressCallback | None = None,
    label: str = "position",
) -> CaptureResult:
    """Move to each position not in ``result.skipped`` and ``take(index, target, moved)`` there.

    The engine is stopped when anything fails or Ctrl-C arrives; ``result`` says what was
    captured and how long it took either way.
    """
    done = set(result.skipped)
    t0 = time.monotonic()
    try:
        for i, rel in enumerate(positions_mm):
            if i in done:
                continue
            target = start_mm + rel
            moved = engine.move(target)
            take(i, target, moved)
            result.captured.append(i)
            if progress is not None:
                message = f"{label} {i} at {moved.caliper_mm:.3f} mm"
                progress(len(done) + len(result.captured), len(positions_mm), message)
    except BaseException:
        engine.stop()
        raise
    finally:
        result.seconds = time.monotonic() - t0
    return result


@dataclass(frozen=True)
class CaptureProgress:
    """A snapshot of a running capture.

    Attributes
    ----------
    done, total
        Frames in the burst directory, frames of the plan.
    index
        The frame being taken (or the last one stored); None before the first.
    target_mm
        The commanded stage position of that frame.
    caliper_mm
        Where the caliper found the carriage after the last move.
    state
        ``starting``, ``moving``, ``acquiring``, ``stored``, ``finished``, ``cancelled``
        or ``failed``.
    """

    done: int = 0
    total: int = 0
    index: int | None = None
    target_mm: float | None = None
    caliper_mm: float | None = None
    state: str = "starting"


def load_progress(out: str | Path) -> Manifest | None:
    """The manifest of a partly captured burst, or None if there is none yet."""
    try:
        return read_manifest(out)
    except InputFormatError as e:
        raise InputFormatError(f"{e}; move it away to start over") from e


class BurstRunner:
    """One capture of one frame at each stage position into a burst directory.

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
        Extra top-level manifest fields (``optics``, ``stage``, ``bayer``, ``plan``...).
    progress
        Called as ``progress(done, total, message)`` after each frame is stored.
    on_frame
        Called as ``on_frame(directory, manifest, index)`` for every frame of the burst
        once its file and manifest entry are on disk: first for the frames already present
        (resuming, in index order), then for each new one. It must return at once and not
        raise (the hardware waits).
    """

    def __init__(
        self,
        engine: Engine,
        positions_mm: Sequence[float],
        out: str | Path,
        *,
        start_mm: float,
        top: Mapping[str, Any] | None = None,
        progress: ProgressCallback | None = None,
        on_frame: FrameCallback | None = None,
    ) -> None:
        self.engine = engine
        self.positions_mm = list(positions_mm)
        self.directory = Path(out)
        self.start_mm = start_mm
        self.top = dict(top or {})
        self._progress_cb = progress
        self._on_frame = on_frame
        self._cancel = threading.Event()
        self._lock = threading.Lock()
        self._stopped = False
        self._progress = CaptureProgress(total=len(self.positions_mm))

    @property
    def progress(self) -> CaptureProgress:
        with self._lock:
            return self._progress

    def _report(self, **changes: Any) -> None:
        with self._lock:
            self._progress = replace(self._progress, **changes)

    def cancel(self) -> None:
        """Stop after the frame in hand (or before the next move); the hardware is stopped."""
        self._cancel.set()

    def stop_hardware(self) -> None:
        """Stop the engine once (errors, cancel and Ctrl-C may all ask)."""
        with self._lock:
            if self._stopped:
                return
            self._stopped = True
        self.engine.stop()

    def _start(self) -> Manifest:
        root = self.directory
        (root / "frames").mkdir(parents=True, exist_ok=True)
        plan_key = {"start_mm": self.start_mm, "positions_mm": list(self.positions_mm)}
        manifest = load_progress(root)
        if manifest is None:
            top = {"version": VERSION, "frames": [], **self.top, "capture": plan_key}
            try:
                return Manifest.from_json(top)
            except ValueError as e:
                raise InputFormatError(f"manifest fields given for {root}: {e}") from e
        if manifest.extra.get("capture") != plan_key:
            raise InputFormatError(
                f"{root / MANIFEST}: holds a burst of another plan or start position; "
                "choose a new --out or remove it"
            )
        present = [e for e in manifest.frames if e.index is not None and (root / e.file).exists()]
        return replace(manifest, frames=tuple(present))

    def run(self) -> CaptureResult:
        """Capture the frames still missing, in the calling thread."""
        root = self.directory
        resumed = (root / MANIFEST).exists()
        manifest = self._start()
        bayer_known = resumed or "bayer" in self.top
        done = sorted(e.index for e in manifest.frames if e.index is not None)
        result = CaptureResult(root, skipped=list(done))
        total = len(self.positions_mm)
        self._report(done=len(done))
        t0 = time.monotonic()
        if self._on_frame is not None:
            for i in done:
                self._on_frame(root, manifest, i)
        try:
            for i, rel in enumerate(self.positions_mm):
                if i in done:
                    continue
                if self._cancel.is_set():
                    break
                target = self.start_mm + rel
                self._report(index=i, target_mm=target, state="moving")
                moved = self.engine.move(target)
                self._report(caliper_mm=moved.caliper_mm, state="acquiring")
                if self._cancel.is_set():
                    break
                tiff, meta = self.engine.acquire()
                name = f"frames/{i:04d}.tif"
                write_atomic(root / name, tiff, sync=True)
                entry = FrameEntry(
                    file=name,
                    index=i,
                    stage_mm=round(target, 6),
                    caliper_mm=moved.caliper_mm,
                    frame=meta.get("frame"),
                    timestamp_ns=meta.get("timestamp_ns"),
                )
                manifest = manifest.with_frame(entry)
                if not bayer_known:
                    manifest, bayer_known = replace(manifest, bayer=meta.get("bayer")), True
                write_manifest(root, manifest, sync=True)
                result.captured.append(i)
                self._report(done=len(manifest.frames), state="stored")
                if self._on_frame is not None:
                    self._on_frame(root, manifest, i)
                if self._progress_cb is not None:
                    message = f"frame {i} at {moved.caliper_mm:.3f} mm"
                    self._progress_cb(len(manifest.frames), total, message)
        except BaseException:
            self._report(state="failed")
            self.stop_hardware()
            raise
        finally:
            result.seconds = time.monotonic() - t0
        if self._cancel.is_set() and len(manifest.frames) < total:
            self.stop_hardware()
            result.cancelled = True
            self._report(state="cancelled")
        else:
            self._report(state="finished")
        return result

    def start(self) -> CaptureStatus:
        """Run the capture in a background thread; its handle."""
        return CaptureStatus(self)


class CaptureStatus:
    """Handle of a capture running in the background (:meth:`BurstRunner.start`).

    ``progress`` is a :class:`CaptureProgress` snapshot; ``done`` says whether it ended;
    ``cancel()`` stops it after the frame in hand (frames stored so far stay: run it again
    to complete); ``wait(timeout)`` returns the :class:`CaptureResult` or raises the
    capture's error; callbacks run once it has ended. Ctrl-C inside ``wait`` stops the
    hardware before the KeyboardInterrupt goes on.
    """

    def __init__(self, runner: BurstRunner) -> None:
        self.runner = runner
        self._finished = threading.Event()
        self._lock = threading.Lock()
        self._callbacks: list[Callable[[CaptureStatus], None]] = []
        self.result: CaptureResult | None = None
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="burst-capture", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            self.result = self.runner.run()
        except BaseException as e:  # handed to wait(), which raises it in the caller
            self.error = e
        with self._lock:
            self._finished.set()
            callbacks, self._callbacks = self._callbacks, []
        for fn in callbacks:
            fn(self)

    @property
    def progress(self) -> CaptureProgress:
        return self.runner.progress

    @property
    def done(self) -> bool:
        return self._finished.is_set()

    def cancel(self) -> None:
        """Ask the capture to stop after the frame in hand; :meth:`wait` returns its result."""
        self.runner.cancel()

    def add_callback(self, fn: Callable[[CaptureStatus], None]) -> None:
        """Call ``fn(self)`` once the capture has ended (at once if it already has)."""
        with self._lock:
            if not self._finished.is_set():
                self._callbacks.append(fn)
                return
        fn(self)

    def wait(self, timeout: float | None = None) -> CaptureResult:
        """Block until the capture ends; its result, or its error raised here.

        Raises
        ------
        CaptureTimeout
            When it has not ended within ``timeout`` seconds (it goes on running).
        """
        deadline = None if timeout is None else time.monotonic() + timeout
        try:
            while not self._finished.wait(0.05):
                if deadline is not None and time.monotonic() > deadline:
                    p = self.progress
                    raise CaptureTimeout(
                        f"burst capture into {self.runner.directory} not finished within "
                        f"{timeout} s ({p.done}/{p.total} frames, {p.state})"
                    )
        except KeyboardInterrupt:
            self.runner.cancel()
            self.runner.stop_hardware()
            self._thread.join(timeout=5.0)  # let the frame in hand be stored or dropped
            raise
        if self.error is not None:
            raise self.error
        assert self.result is not None
        return self.result


def capture_burst(
    engine: Engine, positions_mm: Sequence[float], out: str | Path, **options: Any
) -> CaptureResult:
    """Capture one frame at each stage position, blocking.

    ``options`` (``start_mm`` required, ``top``, ``progress``, ``on_frame``) are those of
    :class:`BurstRunner`; ``BurstRunner(...).start()`` runs the same in the background.
    """
    return BurstRunner(engine, positions_mm, out, **options).run()
