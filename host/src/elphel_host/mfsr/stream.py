"""Fuse a burst while it is being captured: per-frame work as frames arrive, then the solve.

``elphel burst capture --fuse`` hands every stored frame to a :class:`FusionStream`. A
background thread loads it, converts it and registers it against the first frame, which
is the expensive part of fusion that does not need the other frames; while the stage moves
and settles for the next frame there is time for it. When the last frame is in, only the
reconstruction remains (:meth:`FusionStream.finish`).

The result is the one ``elphel mfsr BURST_DIR`` computes on the finished directory, bit for
bit: each frame is registered exactly as :func:`~elphel_host.mfsr.registration.register_frames`
registers it within the whole burst (against frame 0, with the stage/optics prior of
:meth:`~elphel_host.burst.manifest.Manifest.stage_prior_px`), frames are read and checked by
:func:`~elphel_host.burst.io.read_frame` as :func:`~elphel_host.burst.io.read_burst` reads
them, and the reconstruction is
:func:`~elphel_host.mfsr.fuse.fuse_registered`, as in ``fuse_frames``.

Nothing is written to the burst directory here. A failure (a frame that cannot be read, an
error in the reconstruction) is kept and raised by :meth:`FusionStream.finish` as a
:class:`~elphel_host.errors.FusionError`; :meth:`FusionStream.frame_stored` never raises,
so the capture goes on and keeps its frames.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elphel_host.burst.io import read_frame
from elphel_host.burst.manifest import FrameEntry, Manifest
from elphel_host.closing import Closing
from elphel_host.errors import FusionError, InputFormatError
from elphel_host.mfsr.bayer import bayer_luma
from elphel_host.mfsr.fuse import FusionResult, fuse_registered, register_lumas
from elphel_host.mfsr.output import fused_meta, write_image
from elphel_host.mfsr.registration import FrameRegistration
from elphel_host.mfsr.robust_config import DEFAULT_CONFIG, RobustConfig
from elphel_host.mfsr.scale import MAX_SCALE, MIN_SCALE, check_scale

F32 = NDArray[np.float32]

STREAM_METHODS = ("robust", "baseline")


@dataclass(frozen=True)
class _Job:
    """What the worker needs about one stored frame: its entry in the manifest as stored."""

    index: int
    path: Path
    entry: FrameEntry
    manifest: Manifest

    @property
    def bayer(self) -> str | None:
        return self.manifest.bayer


@dataclass
class _Prepared:
    job: _Job
    image: F32  # the frame as fuse_frames sees it: float32 of the uint16 DN
    luma: F32 | None  # what registration sees (None once registered, to save memory)
    registration: FrameRegistration | None = None
    prior_used: bool = False


class FusionStream(Closing):
    """Prepare frames for fusion as they are captured; reconstruct when all are in.

    Parameters
    ----------
    frames
        Number of frames the burst will hold (the plan's); frame 0 is the reference.
    scale
        Integer up-sampling factor, 1..8 (:mod:`elphel_host.mfsr.scale`).
    method
        ``robust`` or ``baseline`` (as ``elphel mfsr --method``).
    config
        Options of the robust method.
    use_prior
        Use the manifest's stage/optics prior for registration (``elphel mfsr`` does,
        unless ``--no-prior``).
    min_correlation
        Registration validation threshold (as :func:`~elphel_host.mfsr.fuse.fuse_frames`).

    Notes
    -----
    Use it as a context manager: leaving the block early (an error, Ctrl-C) stops the
    worker. :meth:`frame_stored` is the hook for
    :func:`~elphel_host.burst.capture.capture_burst`'s ``on_frame``.
    """

    def __init__(
        self,
        *,
        frames: int,
        scale: int,
        method: str = "robust",
        config: RobustConfig = DEFAULT_CONFIG,
        use_prior: bool = True,
        min_correlation: float = 0.5,
    ) -> None:
        if method not in STREAM_METHODS:
            raise ValueError(f"method={method!r}; allowed: {', '.join(STREAM_METHODS)}")
        if frames < 1:
            raise ValueError(f"frames={frames}; allowed: >= 1")
        self.frames = frames
        self.scale = check_scale(scale, minimum=MIN_SCALE, maximum=MAX_SCALE)
        self.method = method
        self.config = config
        self.use_prior = use_prior
        self.min_correlation = min_correlation
        self.busy_seconds = 0.0  # worker time spent on frames (load, convert, register)
        self._jobs: queue.Queue[_Job | None] = queue.Queue()
        self._lock = threading.Lock()
        self._prepared: dict[int, _Prepared] = {}
        self._waiting: list[int] = []  # loaded, waiting for the reference frame
        self._error: BaseException | None = None
        self._error_at: str = ""
        self._cancel = threading.Event()
        self._thread = threading.Thread(target=self._work, name="mfsr-stream", daemon=True)
        self._thread.start()

    # -- the capture's side ---------------------------------------------------------------
    def frame_stored(self, directory: Path, manifest: Manifest, index: int) -> None:
        """Queue frame ``index`` of the burst in ``directory``; returns at once, never raises.

        ``manifest`` is the burst's manifest as just written (frozen: it is kept as it is).
        """
        try:
            entry = manifest.entry(index)
            job = _Job(index, Path(directory) / entry.file, entry, manifest)
        except Exception as e:  # a hook must not break the capture: keep it for finish()
            self._fail(e, f"frame {index}")
            return
        self._jobs.put(job)

    def status(self) -> str:
        """One line for progress, e.g. ``registered 7/16, excluded [3]``."""
        done = self.registered
        with self._lock:
            excluded = sorted(
                i
                for i, p in self._prepared.items()
                if p.registration is not None and not p.registration.ok
            )
            error, where = self._error, self._error_at
        if error is not None:
            return f"failed ({where}: {error})"
        text = f"registered {done}/{self.frames}"
        return text + (f", excluded {excluded}" if excluded else "")

    @property
    def failed(self) -> bool:
        return self._error is not None

    @property
    def registered(self) -> int:
        """Frames registered so far (the reference counts)."""
        with self._lock:
            return sum(p.registration is not None for p in self._prepared.values())

    @property
    def bayer(self) -> str | None:
        """The burst's Bayer pattern (None for mono, or before the first frame)."""
        with self._lock:
            first = next(iter(self._prepared.values()), None)
        return None if first is None else first.job.bayer

    # -- the worker -------------------------------------------------------------------------
    def _fail(self, error: BaseException, where: str) -> None:
        with self._lock:
            if self._error is None:
                self._error, self._error_at = error, where

    def _work(self) -> None:
        while True:
            job = self._jobs.get()
            if job is None or self._cancel.is_set():
                return
            if self._error is not None:
                continue  # the result is lost anyway; keep draining, don't burn CPU
            t0 = time.perf_counter()
            try:
                self._prepare(job)
            except Exception as e:  # reported by finish(); the capture must go on
                self._fail(e, f"frame {job.index}")
            self.busy_seconds += time.perf_counter() - t0

    def _load(self, job: _Job) -> F32:
        # read and checked as read_burst does, so that a frame elphel mfsr would refuse fails
        with self._lock:
            first = next(iter(self._prepared.values()), None)
        if first is not None and job.bayer != first.job.bayer:
            raise InputFormatError(
                f"{job.path}: bayer={job.bayer!r}; allowed: {first.job.bayer!r} (the burst's)"
            )
        like = None if first is None else (first.image.shape, first.job.path.name)
        return np.asarray(read_frame(job.path, bayer=job.bayer, like=like), dtype=np.float32)

    def _prepare(self, job: _Job) -> None:
        image = self._load(job)
        luma = image if job.bayer is None else bayer_luma(image)
        p = _Prepared(job, image, luma)
        with self._lock:
            self._prepared[job.index] = p
        if job.index == 0:
            with self._lock:
                p.registration = FrameRegistration(0, (0.0, 0.0), 1.0, "reference", True)
            pending, self._waiting = self._waiting, []
            for i in pending:
                self._register(self._prepared[i], use_prior=self.use_prior)
        elif 0 in self._prepared:
            self._register(p, use_prior=self.use_prior)
        else:  # resumed with frame 0 missing: register once it is captured
            self._waiting.append(job.index)

    def _register(self, p: _Prepared, *, use_prior: bool) -> None:
        """Register one frame to frame 0 exactly as register_frames does within the burst."""
        ref = self._prepared[0]
        assert ref.luma is not None
        luma = p.luma if p.luma is not None else self._luma(p)
        prior = None
        if use_prior:
            pair = replace(p.job.manifest, frames=(ref.job.entry, p.job.entry))
            prior = pair.stage_prior_px()
        r = register_lumas(
            [ref.luma, luma],
            mosaic=p.job.bayer is not None,
            prior=prior,
            min_correlation=self.min_correlation,
        )[1]
        reg = replace(r, index=p.job.index)
        with self._lock:
            p.registration, p.prior_used, p.luma = reg, prior is not None, None

    def _luma(self, p: _Prepared) -> F32:
        return p.image if p.job.bayer is None else bayer_luma(p.image)

    # -- the end ----------------------------------------------------------------------------
    def finish(self) -> FusionResult:
        """Wait for the frames in flight, then reconstruct; the result of ``elphel mfsr``.

        Raises
        ------
        FusionError
            When a frame could not be prepared, frames are missing, or the reconstruction
            failed; the message names the frame or the step.
        """
        self._jobs.put(None)
        self._thread.join()
        if self._error is not None:
            raise FusionError(f"fusion failed at {self._error_at}: {self._error}") from self._error
        missing = [i for i in range(self.frames) if i not in self._prepared]
        if missing:
            raise FusionError(
                f"fusion has frames {sorted(self._prepared)}; allowed: all of 0..{self.frames - 1} "
                f"(missing {missing})"
            )
        t0 = time.perf_counter()
        try:
            items = [self._prepared[i] for i in range(self.frames)]
            # Manifest.stage_prior_px gives no prior at all when any frame lacks a position:
            # frames registered with one are then registered again without
            if self.use_prior and not all(p.prior_used for p in items[1:]):
                for p in items[1:]:
                    if p.prior_used:
                        self._register(p, use_prior=False)
            regs = [p.registration for p in items]
            assert all(r is not None for r in regs)
            image, info = fuse_registered(
                [p.image for p in items],
                regs,  # type: ignore[arg-type]
                scale=self.scale,
                method=self.method,
                bayer=items[0].job.bayer,
                config=self.config,
            )
        except Exception as e:
            raise FusionError(f"fusion failed in the {self.method} reconstruction: {e}") from e
        seconds = self.busy_seconds + time.perf_counter() - t0
        final = [r for r in regs if r is not None]
        excluded = [r.index for r in final if not r.ok]
        return FusionResult(image, self.method, final, excluded, seconds, info)

    def close(self) -> None:
        """Stop the worker without a result (idempotent)."""
        self._cancel.set()
        self._jobs.put(None)
        # a frame being registered finishes within a fraction of a second; the thread
        # is a daemon, so an interpreter exiting on Ctrl-C does not wait for it
        self._thread.join(timeout=5.0)


def finish_and_write(
    stream: FusionStream,
    out: str | Path,
    *,
    burst: str | Path,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Finish ``stream`` and write the fused image atomically (as ``elphel mfsr`` writes it).

    Parameters
    ----------
    stream
        The fusion fed by the capture, all frames stored.
    out
        The fused TIFF (16-bit DN; a PNG preview goes next to it).
    burst
        The burst directory (recorded in the TIFF's metadata).
    progress
        Called with a line of text before and after the reconstruction.

    Returns
    -------
    dict
        What ``elphel mfsr --json`` reports (per-frame registration, excluded frames with
        the reason, ...) plus ``registered_before_finish`` (frames the background had
        registered when the capture ended) and ``after_capture_s`` (wall time from this
        call, i.e. the last frame stored, to the fused file written).

    Raises
    ------
    FusionError
        Nothing is written then (a previous file at ``out`` is left as it was).
    """
    t0 = time.monotonic()
    registered = stream.registered
    if progress is not None:
        rest = "" if registered == stream.frames else "registering the rest, then "
        progress(f"{stream.status()}; {rest}reconstructing ({stream.method} x{stream.scale})")
    result = stream.finish()
    meta = fused_meta(
        method=result.method,
        scale=stream.scale,
        burst=burst,
        bayer=stream.bayer,
    )
    try:
        written = write_image(out, result.image, as_float=False, meta=meta)
    except OSError as e:
        raise FusionError(f"fusion: cannot write {out}: {e}") from e
    after = time.monotonic() - t0
    if progress is not None:
        progress(f"{written['out']} written {after:.2f} s after the last frame")
    return {
        "burst": str(burst),
        **written,
        **result.report(),
        "registered_before_finish": registered,
        "after_capture_s": round(after, 3),
    }
