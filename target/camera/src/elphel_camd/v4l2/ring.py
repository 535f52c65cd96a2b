"""The frames of one port as the driver delivered them, the newest few, by frame number.

Frames are kept in their delivered bytes (packed RAW10 stays 5 bytes for 4 pixels) and
unpacked only when one is fetched: placing a frame costs one copy, and the frames nobody
asks for are never unpacked.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from elphel_camd.errors import FrameNotAvailableError
from elphel_camd.v4l2.source import StreamFormat
from elphel_camd.v4l2.unpack import FrameData, frame_bytes, unpack


@dataclass
class _Slot:
    data: NDArray[np.uint8]
    frame: int = -1
    timestamp_ns: int = 0
    stream_format: StreamFormat | None = None


@dataclass(frozen=True)
class RingFrame:
    """A frame taken from the ring: its pixels, number and capture time."""

    image: NDArray[np.uint16]
    frame: int
    timestamp_ns: int
    stream_format: StreamFormat


class FrameRing:
    """The newest ``slots`` frames of a port.

    Parameters
    ----------
    slots
        Frames kept; the oldest is overwritten by the next.
    """

    def __init__(self, slots: int) -> None:
        if slots < 1:
            raise ValueError(f"a frame ring needs 1 or more slots, got {slots}")
        self._slots = [_Slot(np.empty(0, np.uint8)) for _ in range(slots)]
        self._next = 0
        self.newest = 0  # frame numbers start at 1
        self._cond = threading.Condition()

    def put(self, data: FrameData, *, frame: int, timestamp_ns: int, fmt: StreamFormat) -> None:
        """Copy a delivered frame into the oldest slot and wake those waiting for it."""
        lines = frame_bytes(data, height=fmt.height, stride=fmt.stride)
        with self._cond:
            slot = self._slots[self._next]
            if slot.data.size != lines.size:
                slot.data = np.empty(lines.size, np.uint8)
            np.copyto(slot.data.reshape(lines.shape), lines)
            slot.frame, slot.timestamp_ns, slot.stream_format = frame, timestamp_ns, fmt
            self._next = (self._next + 1) % len(self._slots)
            self.newest = frame
            self._cond.notify_all()

    def frames(self) -> list[int]:
        """Frame numbers held, oldest first."""
        with self._cond:
            return sorted(s.frame for s in self._slots if s.frame >= 0)

    def get(self, frame: int) -> RingFrame:
        """A held frame, unpacked (FrameNotAvailableError if it is not held)."""
        with self._cond:
            for slot in self._slots:
                if slot.frame == frame and slot.stream_format is not None:
                    data, fmt, ts = slot.data.copy(), slot.stream_format, slot.timestamp_ns
                    break
            else:
                held = self.frames()
                span = f"frames {held[0]}..{held[-1]}" if held else "no frames yet"
                if held and len(held) < held[-1] - held[0] + 1:
                    span += ", with gaps where frames were dropped"
                raise FrameNotAvailableError(f"frame {frame} is not in the ring buffer ({span})")
        image = unpack(data, fmt.format, width=fmt.width, height=fmt.height, stride=fmt.stride)
        return RingFrame(image, frame, ts, fmt)

    def wait_newer(self, than: int, timeout_s: float) -> bool:
        """Wait until a frame newer than ``than`` is held; False on timeout."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self.newest <= than:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self._cond.wait(remaining)
            return True

    def wake(self) -> None:
        """Wake every waiter (the port changed state)."""
        with self._cond:
            self._cond.notify_all()
