"""A Lepton's frames, read in a thread: the frame source a camera port is built on.

`LeptonFrameSource` owns a `VoSPIReader` on a byte source, runs it in a thread, keeps the
newest frames in a ring and tells a listener of each new frame. Its interface is small on
purpose, so a board can combine it with other ports: `open`, `read_frame` (the next frame,
or a recent one by number), `health`, `close`.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any, BinaryIO

from elphel_camd.vospi import telemetry as tm
from elphel_camd.vospi.errors import NotVoSPIError, VoSPIError, VoSPITimeoutError
from elphel_camd.vospi.reader import VoSPIFrame, VoSPIReader
from elphel_camd.vospi.sources import MAX_CLOCK_HZ, ByteSource, FileSource, open_source

log = logging.getLogger(__name__)

RING_FRAMES = 64
READ_TIMEOUT_S = 0.5  # how long the thread waits for bytes before looking at its state
PROBE_TIMEOUT_S = 2.0
LEPTON_UNIQUE_FPS = 106 / 12  # four valid segments in every twelve, 106 segments a second

FrameListener = Callable[[VoSPIFrame], None]


class LeptonFrameSource:
    """Frames of one Lepton from a spidev node, a file or a FIFO.

    Parameters
    ----------
    path
        The spidev node, file or FIFO (`elphel_camd.vospi.open_source`).
    clock_hz
        SPI clock for a spidev node.
    telemetry_location
        Where the telemetry rows are when the stream has them (`telemetry.FOOTER`).
    record
        A binary file that receives every byte the reader consumes (a recording).
    source
        A byte source to use instead of opening ``path`` (a simulated Lepton).
    on_frame
        Called with each new frame, in the reading thread.
    replay_fps
        A regular file (a recording) is replayed at this many frames a second, as the
        Lepton sent them (0: as fast as it is read). Devices and FIFOs keep their own pace.
    """

    def __init__(
        self,
        path: str,
        *,
        clock_hz: int = MAX_CLOCK_HZ,
        telemetry_location: int = tm.FOOTER,
        record: BinaryIO | None = None,
        source: ByteSource | None = None,
        on_frame: FrameListener | None = None,
        replay_fps: float = LEPTON_UNIQUE_FPS,
    ) -> None:
        self.path = path
        self.replay_fps = replay_fps
        self.clock_hz = clock_hz
        self.telemetry_location = telemetry_location
        self.record = record
        self.on_frame = on_frame
        self._source = source
        self._reader: VoSPIReader | None = None
        self._ring: deque[VoSPIFrame] = deque(maxlen=RING_FRAMES)
        self._cond = threading.Condition()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._error: Exception | None = None
        self._ended = False
        self._last_frame_s: float | None = None

    # -- life ------------------------------------------------------------------------------

    def open(self, *, probe_timeout_s: float = PROBE_TIMEOUT_S) -> None:
        """Open the source and start reading; raise at once what can be told early.

        Waits up to ``probe_timeout_s`` for the first good packet: a stream that is not
        VoSPI raises `NotVoSPIError` here. A device that sends nothing yet is not an error
        (`health` reports it, a capture times out).
        """
        if self._source is None:
            self._source = open_source(self.path, clock_hz=self.clock_hz)
        self._reader = VoSPIReader(
            self._source, telemetry_location=self.telemetry_location, record=self.record
        )
        self._thread = threading.Thread(target=self._run, name="vospi-reader", daemon=True)
        self._thread.start()
        deadline = time.monotonic() + probe_timeout_s
        with self._cond:
            while time.monotonic() < deadline:
                if self._error is not None or self._ended or self._reader.counts.good_packets:
                    break
                self._cond.wait(0.02)
        if isinstance(self._error, VoSPIError):
            self.close()
            raise self._error

    def close(self) -> None:
        """Stop the reading thread and close the source (and finish the recording)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5)
        if self._reader is not None:
            self._reader.close_record()
        if self._source is not None:
            self._source.close()
            self._source = None

    # -- the reading thread ----------------------------------------------------------------

    def _run(self) -> None:
        reader = self._reader
        assert reader is not None
        period_s = self._replay_period_s()
        due = time.monotonic()
        while not self._stop.is_set():
            if period_s:
                self._stop.wait(max(0.0, due - time.monotonic()))
                due = max(due, time.monotonic() - period_s) + period_s
            try:
                frame = reader.read_frame(timeout_s=READ_TIMEOUT_S)
            except VoSPITimeoutError:
                continue
            except EOFError:
                self._finish(None if reader.counts.good_packets else self._not_vospi(reader))
                return
            except Exception as e:  # reported by health and captures; the thread ends
                log.error("%s", e)
                self._finish(e)
                return
            with self._cond:
                self._ring.append(frame)
                self._last_frame_s = time.monotonic()
                self._cond.notify_all()
            if self.on_frame is not None:
                self.on_frame(frame)

    def _replay_period_s(self) -> float:
        """Seconds between the frames of a replayed recording (0: not paced)."""
        source = self._source
        if self.replay_fps <= 0 or not isinstance(source, FileSource) or source.fifo:
            return 0.0
        return 1 / self.replay_fps

    def _not_vospi(self, reader: VoSPIReader) -> NotVoSPIError:
        return NotVoSPIError(
            f"{self.path}: not a VoSPI stream: it ended after {reader.counts.bytes_skipped} "
            "bytes without a packet with a good CRC"
        )

    def _finish(self, error: Exception | None) -> None:
        with self._cond:
            self._error = error
            self._ended = True
            self._cond.notify_all()

    # -- frames ----------------------------------------------------------------------------

    def read_frame(self, *, after: int | None = None, timeout_s: float = 10.0) -> VoSPIFrame:
        """The first frame numbered above ``after`` (the next new frame if None).

        Raises `VoSPITimeoutError` when none comes within ``timeout_s`` (wall clock).
        """
        deadline = time.monotonic() + timeout_s
        with self._cond:
            if after is None:
                after = self._ring[-1].number if self._ring else -1
            while True:
                for frame in self._ring:
                    if frame.number > after:
                        return frame
                left = deadline - time.monotonic()
                if self._ended or left <= 0:
                    raise self._no_frame(timeout_s)
                self._cond.wait(min(left, 0.5))

    def recent(self, number: int) -> VoSPIFrame | None:
        """Frame ``number`` if the ring still holds it."""
        with self._cond:
            return next((f for f in self._ring if f.number == number), None)

    def _no_frame(self, timeout_s: float) -> Exception:
        if self._error is not None:
            return VoSPITimeoutError(f"{self.path}: the VoSPI reader stopped: {self._error}")
        if self._ended:
            return VoSPITimeoutError(f"{self.path}: the VoSPI recording has ended")
        detail = self.health()
        return VoSPITimeoutError(
            f"{self.path}: no frame from the Lepton in {timeout_s} s ({detail['state']}, "
            f"{detail['resyncs']} resyncs): check its power, /CS wiring and the SPI device"
        )

    def health(self) -> dict[str, Any]:
        """State of the stream: ``streaming``, ``stalled``, ``ended`` or ``failed``, and counts."""
        reader = self._reader
        counts = reader.counts if reader is not None else None
        with self._cond:
            age = None if self._last_frame_s is None else time.monotonic() - self._last_frame_s
            if self._error is not None:
                state = "failed"
            elif self._ended:
                state = "ended"
            elif age is not None and age < 1.0:
                state = "streaming"
            else:
                state = "stalled"
        out: dict[str, Any] = {
            "state": state,
            "path": self.path,
            "last_frame_age_s": None if age is None else round(age, 3),
            "frames": reader.frames if reader is not None else 0,
            "realigns": counts.realigns if counts is not None else 0,
            "resyncs": counts.resyncs if counts is not None else 0,
            "crc_errors": counts.crc_errors if counts is not None else 0,
            "frames_dropped": reader.assembler.counts.frames_dropped if reader else 0,
        }
        if self._error is not None:
            out["detail"] = str(self._error)
        elif state != "streaming":
            since = "no frame yet" if age is None else f"no frame for {age:.1f} s"
            out["detail"] = f"{self.path}: {since} ({out['resyncs']} resyncs)"
        return out
