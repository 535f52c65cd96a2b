"""One port's stream: a thread that takes buffers from its node into the frame ring.

The driver's sequence counter numbers the frames (a gap is a dropped frame, counted and
reported); the buffer's timestamp is the frame's time. When the node vanishes the port
says ``disconnected``, reports it, and reopens the node until it returns; a streaming
error restarts the stream. Frame numbers keep increasing across restarts.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Callable
from typing import Any

from elphel_camd.errors import PortDisconnectedError, VideoNodeError
from elphel_camd.v4l2.ring import FrameRing
from elphel_camd.v4l2.shape import Shape
from elphel_camd.v4l2.source import Buffer, FrameSource, StreamFormat

log = logging.getLogger(__name__)

SEQUENCE_MODULO = 1 << 32  # v4l2_buffer.sequence is a __u32
Opener = Callable[[], FrameSource]
# Called as on_frame(port, frame, timestamp_ns) after the frame is in the ring.
OnFrame = Callable[[int, int, int], None]
# Called as on_lost(port, frame) for the last frame of a gap, before the frame after it is
# taken: the schedule moves on as if it had come (a shape due then restarts the stream).
OnLost = Callable[[int, int], None]
# Called as on_event(kind, payload): "port" for a change of state, "error" for drops
# (error "frames_dropped") and streaming errors (error "v4l2").
OnEvent = Callable[[str, dict[str, Any]], None]


class PortStream:
    """Frames of one V4L2 node into a ring, in a thread of its own.

    Parameters
    ----------
    port
        The sensor port number (for messages and callbacks).
    source
        The node, opened and set to its format.
    opener
        Opens the node again after it vanished.
    ring
        Where frames go.
    buffers
        Driver buffers to stream with.
    on_frame, on_event, on_lost
        Callbacks (see the module's aliases).
    reconnect_s
        Seconds between attempts to reopen a vanished node.
    """

    def __init__(
        self,
        port: int,
        source: FrameSource,
        *,
        opener: Opener,
        ring: FrameRing,
        buffers: int = 4,
        on_frame: OnFrame,
        on_event: OnEvent,
        on_lost: OnLost | None = None,
        reconnect_s: float = 0.5,
    ) -> None:
        self.port = port
        self.source = source
        self.ring = ring
        self.state = "starting"
        self.detail = ""
        self.frames = 0
        self.drops = 0
        self.restarts = 0
        self.period_ns = 0  # recent time from one frame to the next
        self._opener = opener
        self._buffers = buffers
        self._on_frame = on_frame
        self._on_event = on_event
        self._on_lost = on_lost
        self.reshapes = 0  # shape changes so far
        self._reconnect_s = reconnect_s
        self._last_sequence: int | None = None
        self._last_frame = 0
        self._last_ts = 0
        self._stop = threading.Event()
        # Held while a buffer is taken and while the shape changes: one at a time.
        self._io = threading.RLock()
        self._thread = threading.Thread(target=self._run, name=f"v4l2-port{port}", daemon=True)

    @property
    def last_frame(self) -> int:
        """Number of the newest frame (0 before the first)."""
        return self._last_frame

    def start(self) -> None:
        """Start streaming (raises what the node raises) and the thread."""
        self.source.start(self._buffers)
        self._set_state("streaming")
        self._thread.start()

    def close(self) -> None:
        """Stop the thread and release the node."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(5.0)
        try:
            self.source.close()
        except OSError as e:
            log.debug("port %d: closing %s: %s", self.port, self.source.path, e)
        self.ring.wake()

    def _set_state(self, state: str, detail: str = "") -> None:
        if state == self.state and detail == self.detail:
            return
        self.state, self.detail = state, detail
        self.ring.wake()
        self._on_event("port", {"port": self.port, "state": state, "detail": detail})

    def reshape(self, shape: Shape) -> StreamFormat:
        """Stop the stream, give the node a new shape, start again; the format read back.

        Called between two frames (from the frame callback, or from another thread, which
        waits for the frame being taken): the next frame is the first of the new shape and
        gets the next frame number. A shape the driver refuses leaves the old one
        streaming and raises.
        """
        with self._io:
            self.source.stop()
            self._last_sequence = None
            self.reshapes += 1
            try:
                return self.source.set_shape(shape)
            finally:
                self.source.start(self._buffers)

    def _run(self) -> None:
        while not self._stop.is_set():
            with self._io:
                self._step()

    def _step(self) -> None:
        """Take one buffer (or notice that none came, or that the node failed)."""
        try:
            buf = self.source.dequeue(0.2)
        except PortDisconnectedError as e:
            self._set_state("disconnected", str(e))
            self._reconnect()
            return
        except OSError as e:
            self._restart(f"{self.source.path}: streaming failed ({e}); restarting")
            return
        if buf is None:
            return
        try:
            self._take(buf)
        except Exception as e:  # a frame that cannot be taken must not end the stream
            log.exception("port %d: frame of sequence %d not taken", self.port, buf.sequence)
            self._restart(f"{self.source.path}: a frame could not be taken ({e}); restarting")

    def _take(self, buf: Buffer) -> None:
        frame = self._number(buf.sequence)
        if self._stale_after_loss(frame):
            return
        try:
            if buf.error:
                self._on_event(
                    "error",
                    {
                        "port": self.port,
                        "frame": frame,
                        "error": "v4l2",
                        "detail": f"{self.source.path}: frame {frame} flagged as corrupt",
                    },
                )
            self.ring.put(
                buf.data, frame=frame, timestamp_ns=buf.timestamp_ns, fmt=self.source.stream_format
            )
        finally:
            with contextlib.suppress(PortDisconnectedError):  # the next dequeue reports it
                self.source.requeue(buf)
        if self._last_ts and buf.timestamp_ns > self._last_ts:
            gap = frame - self._last_frame
            self.period_ns = (buf.timestamp_ns - self._last_ts) // max(gap, 1)
        self._last_frame, self._last_ts = frame, buf.timestamp_ns
        self.frames += 1
        self._on_frame(self.port, frame, buf.timestamp_ns)

    def _stale_after_loss(self, frame: int) -> bool:
        """After lost frames, move the schedule on; True if that changed the shape.

        The buffer then holds the old shape and belongs to the stopped stream: it is
        dropped, and the new stream's first frame takes its number.
        """
        if self._on_lost is None or not self._last_frame or frame <= self._last_frame + 1:
            return False
        shapes = self.reshapes
        self._on_lost(self.port, frame - 1)
        if self.reshapes == shapes:
            return False
        self._last_frame = frame - 1
        return True

    def _number(self, sequence: int) -> int:
        """The frame number of a buffer's sequence; counts and reports a gap as drops."""
        last = self._last_sequence
        self._last_sequence = sequence
        if last is None:  # first buffer of a stream: continue after the last frame
            return self._last_frame + 1
        step = (sequence - last) % SEQUENCE_MODULO
        if step > 1:
            self.drops += step - 1
            first = self._last_frame + 1
            self._on_event(
                "error",
                {
                    "port": self.port,
                    "frame": first + step - 1,
                    "error": "frames_dropped",
                    "detail": f"{self.source.path}: {step - 1} frame(s) lost before frame "
                    f"{first + step - 1} ({self.drops} in all)",
                    "frames": step - 1,
                    "first": first,
                    "last": first + step - 2,
                    "total": self.drops,
                },
            )
        return self._last_frame + max(step, 1)

    def _restart(self, reason: str) -> None:
        log.warning("port %d: %s", self.port, reason)
        self._on_event("error", {"port": self.port, "error": "v4l2", "detail": reason})
        self.restarts += 1
        with contextlib.suppress(OSError):
            self.source.stop()
        self._last_sequence = None
        try:
            self.source.start(self._buffers)
        except PortDisconnectedError as e:
            self._set_state("disconnected", str(e))
            self._reconnect()
        except (VideoNodeError, OSError) as e:
            self._set_state("failed", str(e))
            self._stop.wait(self._reconnect_s)

    def _reconnect(self) -> None:
        """Close the vanished node and reopen it until it returns (or the port closes)."""
        with contextlib.suppress(OSError):
            self.source.close()
        self._last_sequence = None
        while not self._stop.wait(self._reconnect_s):
            try:
                source = self._opener()
                source.start(self._buffers)
            except (VideoNodeError, OSError) as e:
                log.debug("port %d: %s not back yet: %s", self.port, self.source.path, e)
                continue
            self.source = source
            self.restarts += 1
            self._set_state("streaming")
            return
