"""Capture: frames of a port with their metadata, bursts, and the threads captures wait in.

`FrameCapture` takes a port's frames from the board with the parameters each was taken
with; a burst holds its frames (on a board that can) and their parameters until the
consumer has taken each. `CameraService` owns one and its ``capture`` and ``burst`` call
it. `CapturePool` runs the waits for frames apart from other requests and refuses one too
many with `CaptureBusyError`.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections import Counter
from collections.abc import Callable, Generator, Mapping
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

from elphel_camd.boards.base import Board, Frame
from elphel_camd.errors import CameraError, FrameNotAvailableError, ParameterRangeError
from elphel_camd.frame_metadata import frame_metadata
from elphel_camd.sensors import SensorDriver
from elphel_camd.sequencer import MAX_AHEAD, PortSequencer

T = TypeVar("T")


class CaptureBusyError(CameraError):
    """Too many captures are waiting for frames already (the capture wait pool is full)."""


class CapturePool:
    """The threads that wait for frames, apart from the pool that serves other requests.

    A capture can wait a long time (a stopped trigger waits for its timeout); here such
    waits take at most ``workers`` threads, and requests beyond ``max_waiting`` are refused
    with `CaptureBusyError` instead of queueing without end, so parameter reads and writes
    never wait for captures.

    Parameters
    ----------
    workers
        Threads that wait for frames (and form their images) at the same time.
    max_waiting
        Captures running or queued at most; one more is refused.
    """

    def __init__(self, workers: int = 16, max_waiting: int = 64) -> None:
        self.workers = workers
        self.max_waiting = max_waiting
        self.waiting = 0
        self._executor = ThreadPoolExecutor(workers, thread_name_prefix="camd-capture")

    async def run(self, fn: Callable[[], T]) -> T:
        """``fn()`` in a capture thread (CaptureBusyError if ``max_waiting`` are in)."""
        if self.waiting >= self.max_waiting:
            raise CaptureBusyError(
                f"capture wait pool full: {self.waiting} captures are waiting for frames "
                f"(limit {self.max_waiting}); retry later"
            )
        self.waiting += 1  # only the event loop's thread counts
        try:
            return await asyncio.get_running_loop().run_in_executor(self._executor, fn)
        finally:
            self.waiting -= 1

    def close(self) -> None:
        self._executor.shutdown(wait=False, cancel_futures=True)


class FrameCapture:
    """A board's frames with their metadata, and bursts that hold their frames.

    Parameters
    ----------
    board
        The board the frames come from.
    sequencers
        The frame sequencer of each port with a sensor.
    sensor
        The driver on a port, raising for a port without one (`CameraService.sensor`).
    params
        A port's parameters for a frame (`CameraService.params`).
    """

    def __init__(
        self,
        board: Board,
        sequencers: Mapping[int, PortSequencer],
        *,
        sensor: Callable[[int], SensorDriver],
        params: Callable[..., dict[str, int]],
    ) -> None:
        self.board = board
        self._sequencers = sequencers
        self._sensor = sensor
        self._params = params
        # Parameters of the frames a burst holds, taken when each frame starts: a held
        # frame can be sent after the sequencer's history has forgotten it.
        self._held_params: dict[int, dict[int, dict[str, int] | None]] = {
            port: {} for port in sequencers
        }
        self._held_counts: dict[int, Counter[int]] = {port: Counter() for port in sequencers}
        self._held_lock = threading.Lock()

    def on_frame_sync(self, port: int, frame: int) -> None:
        """Keep the parameters of a frame that starts now if a burst holds it."""
        held = self._held_params[port]
        if frame in held:
            params = self._params(port, frame=frame)
            with self._held_lock:
                if frame in held:
                    held[frame] = params

    def capture(self, port: int, *, frame: int | None = None) -> tuple[Frame, dict[str, Any]]:
        """The next frame of a port (or a recent one) and its metadata."""
        driver = self._sensor(port)
        self._check_frame(port, frame)
        got = self.board.capture(port, frame=frame)
        with self._held_lock:
            params = self._held_params[port].get(got.frame)
        if params is None:
            params = self._params(port, frame=got.frame)
        metadata = frame_metadata(
            got, port=port, sensor=driver.model, bayer=driver.bayer, params=params
        )
        return got, metadata

    def _check_frame(self, port: int, frame: int | None) -> None:
        if frame is None:
            return
        newest = self._sequencers[port].this_frame
        if frame > newest + MAX_AHEAD:
            raise FrameNotAvailableError(
                f"port {port}: frame {frame} is not taken yet (current frame {newest}; "
                f"capture waits for at most {MAX_AHEAD} frames ahead)"
            )

    def burst(
        self, port: int, count: int, *, frame: int | None = None
    ) -> Generator[tuple[Frame, dict[str, Any]], None, None]:
        """``count`` consecutive frames of a port, from the next one (or from ``frame``).

        On a board that can hold frames (``pin_frames``) every frame of the burst is held
        from the start until the consumer has taken it, so a consumer slower than the
        frame rate (a full-resolution burst over the network) still gets all of them.
        Elsewhere a frame overwritten in the ring before it was fetched raises
        `FrameNotAvailableError`. Either way the burst yields every frame or raises.
        """
        if count < 1:
            raise ParameterRangeError("count", count, "1 or more")
        pin = getattr(self.board, "pin_frames", None)
        release = getattr(self.board, "release_frames", None)
        if pin is None or release is None:
            first = self.capture(port, frame=frame)
            yield first
            for k in range(1, count):
                yield self.capture(port, frame=first[0].frame + k)
            return
        self._sensor(port)
        self._check_frame(port, frame)
        start = self._hold_params(port, count, frame)
        done = start  # frames before this one are released
        try:
            pin(port, count, frame=start)
        except BaseException:
            self._release_params(port, range(start, start + count))
            raise
        try:
            for k in range(count):
                got = self.capture(port, frame=start + k)
                yield got
                release(port, [start + k])
                self._release_params(port, [start + k])
                done = start + k + 1
        finally:
            release(port, range(done, start + count))
            self._release_params(port, range(done, start + count))

    def _hold_params(self, port: int, count: int, frame: int | None) -> int:
        """Keep the parameters of ``count`` frames from ``frame`` (or the next one)."""
        seq = self._sequencers[port]
        held = self._held_params[port]
        counts = self._held_counts[port]
        with seq.lock, self._held_lock:  # no frame starts in between
            start = seq.this_frame + 1 if frame is None else frame
            for n in range(start, start + count):
                held.setdefault(n, None)
                counts[n] += 1
        for n in range(start, min(start + count, seq.this_frame + 1)):
            with contextlib.suppress(FrameNotAvailableError):
                params = self._params(port, frame=n)
                with self._held_lock:
                    held[n] = params
        return start

    def _release_params(self, port: int, frames: range | list[int]) -> None:
        held = self._held_params[port]
        counts = self._held_counts[port]
        with self._held_lock:
            for n in frames:
                if counts[n] > 1:
                    counts[n] -= 1
                else:
                    counts.pop(n, None)
                    held.pop(n, None)
