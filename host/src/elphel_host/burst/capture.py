"""Capture a planned burst: move the stage, let it settle, take a frame, record — resumable.

An engine knows the hardware (closed-loop stage moves, the camera's next frame, stopping);
the runner (:class:`BurstRunner`) owns the order, the progress, cancelling, resuming, where
frames go and what happens on failure. Each frame is written to its file first (temporary
name, then rename) and then entered in the manifest (rewritten atomically through
:mod:`elphel_host.burst.io`), so a crash or Ctrl-C at any moment leaves a valid burst
directory holding every frame captured so far exactly once; running the same capture again
takes only the frames still missing. On any error, and on Ctrl-C, the hardware is stopped
before the error goes on.

:meth:`BurstRunner.start` runs a capture in the background and returns its handle
(:class:`CaptureStatus`: ``progress``, ``done``, ``cancel()``, ``wait(timeout)``, callbacks);
:meth:`BurstRunner.run`, or :func:`capture_burst`, blocks instead.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

from elphel_host.burst.io import (
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


# --- Quad bursts --------------------------------------------------------------------------


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
    from elphel_host.tp.io import MANIFEST as QUAD_MANIFEST
    from elphel_host.tp.io import QuadCamera, QuadManifest

    root = Path(out)
    plan_key = {"start_mm": start_mm, "positions_mm": list(positions_mm)}
    manifests: list[Manifest] = []
    for name in QUAD_CAMERAS:
        d = root / name
        (d / "frames").mkdir(parents=True, exist_ok=True)
        m = load_progress(d)
        if m is None:
            m = Manifest.from_json({"version": VERSION, "frames": [], **dict(top or {}),
                                    "capture": plan_key, "quad_camera": int(name[3])})  # fmt: skip
        elif m.extra.get("capture") != plan_key:
            raise InputFormatError(
                f"{d / MANIFEST}: holds a burst of another plan or start position; "
                "choose a new --out or remove it"
            )
        manifests.append(m)
    held = [
        {e.index for e in m.frames if e.index is not None and (root / name / e.file).exists()}
        for m, name in zip(manifests, QUAD_CAMERAS, strict=True)
    ]
    done = sorted(set.intersection(*held))
    result = CaptureResult(root, skipped=list(done))
    total = len(positions_mm)
    t0 = time.monotonic()
    try:
        for i, rel in enumerate(positions_mm):
            if i in done:
                continue
            target = start_mm + rel
            moved = engine.move(target)
            tiffs, quad = engine.acquire_quad()
            name = f"frames/{i:04d}.tif"
            for cam, data in zip(QUAD_CAMERAS, tiffs, strict=True):
                write_atomic(root / cam / name, data, sync=True)
            if not (root / QUAD_MANIFEST).exists():
                qm = QuadManifest(
                    cameras=tuple(
                        QuadCamera(file=cam, position=quad.cameras[c].position,
                                   fields={k: v for k, v in quad.cameras[c].fields.items()
                                           if k in ("port", "sensor")})
                        for c, cam in enumerate(QUAD_CAMERAS)
                    ),
                    bayer=quad.bayer,
                    full_scale_dn=quad.full_scale_dn,
                    optics=dict(optics) if optics else quad.optics,
                )  # fmt: skip
                qm.write(root)
            for c, cam in enumerate(QUAD_CAMERAS):
                fields = quad.cameras[c].fields
                entry = FrameEntry(
                    file=name, index=i, stage_mm=round(target, 6), caliper_mm=moved.caliper_mm,
                    frame=fields.get("frame"), timestamp_ns=fields.get("timestamp_ns"),
                )  # fmt: skip
                # a set only some cameras held is replaced, never entered twice
                kept = tuple(e for e in manifests[c].frames if e.index != i)
                m = replace(replace(manifests[c], frames=kept).with_frame(entry), bayer=quad.bayer)
                manifests[c] = m
                write_manifest(root / cam, m, sync=True)
            result.captured.append(i)
            if progress is not None:
                progress(len(done) + len(result.captured), total,
                         f"set {i} at {moved.caliper_mm:.3f} mm")  # fmt: skip
    except BaseException:
        engine.stop()
        raise
    finally:
        result.seconds = time.monotonic() - t0
    return result
