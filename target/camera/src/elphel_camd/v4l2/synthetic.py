"""Frames made in memory, shaped as a V4L2 node delivers them: for tests and benchmarks.

`SyntheticSource` is a `elphel_camd.v4l2.source.FrameSource` with no device behind it: a
fixed image packed in the node's format, delivered at a frame rate with the driver's
sequence numbers and monotonic timestamps, and IMX219-like controls. A control set
applies to the frames due after it, as a driver's does, and `applied` keeps, by
sequence number, the control values each frame was taken with (the truth a frame's
metadata is checked against); a driver that rounds values to its hardware's steps is
made with ``quantum``. It can crop (the frame is the crop of the image) or offer modes
(a mode of size w x h delivers the image's top-left w x h pixels); either needs the
stream stopped, as drivers do. Faults are injected through ``sim_*`` methods: dropped
frames, a vanished device, a streaming error, silence.
"""

from __future__ import annotations

import bisect
import threading
import time
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from elphel_camd.errors import ControlRefusedError, DeviceBusyError, PortDisconnectedError
from elphel_camd.v4l2.controls import (
    CID_ANALOGUE_GAIN,
    CID_DIGITAL_GAIN,
    CID_EXPOSURE,
    CID_HBLANK,
    CID_HFLIP,
    CID_PIXEL_RATE,
    CID_VFLIP,
)
from elphel_camd.v4l2.formats import (
    RAW_FORMATS,
    Packing,
    RawFormat,
    flipped_bayer,
    raw_format,
)
from elphel_camd.v4l2.shape import Rect, Shape, ShapeOptions
from elphel_camd.v4l2.source import Buffer, ControlInfo, StreamFormat

# Controls of the IMX219's kernel driver in its 3280x2464 mode (reference: frame-paths.md).
IMX219_CONTROLS = (
    ControlInfo(CID_EXPOSURE, "Exposure", 4, 3522, 1, 1600),
    ControlInfo(CID_ANALOGUE_GAIN, "Analogue Gain", 0, 232, 1, 0),
    ControlInfo(CID_DIGITAL_GAIN, "Digital Gain", 256, 4095, 1, 256),
    ControlInfo(CID_HFLIP, "Horizontal Flip", 0, 1, 1, 0),
    ControlInfo(CID_VFLIP, "Vertical Flip", 0, 1, 1, 0),
    ControlInfo(CID_HBLANK, "Horizontal Blanking", 168, 168, 1, 168, read_only=True),
    ControlInfo(CID_PIXEL_RATE, "Pixel Rate", 182_400_000, 182_400_000, 1, 182_400_000, True),
)


APPLIED_FRAMES = 4096  # frames (and control sets) whose values are kept


def pack(image: NDArray[np.uint16], fmt: RawFormat, *, stride: int) -> NDArray[np.uint8]:
    """An image's pixels laid out as the driver writes ``fmt`` (lines ``stride`` bytes apart)."""
    height, width = image.shape
    out = np.zeros((height, stride), np.uint8)
    line = fmt.line_bytes(width)
    if fmt.packing is Packing.BYTE:
        out[:, :line] = image
    elif fmt.packing is Packing.WORD:
        out[:, :line] = image.astype("<u2").view(np.uint8).reshape(height, line)
    elif fmt.bits == 10:
        groups = image.reshape(height, width // 4, 4)
        packed = out[:, :line].reshape(height, width // 4, 5)
        packed[..., :4] = groups >> 2
        packed[..., 4] = sum((groups[..., k] & 3) << (2 * k) for k in range(4))
    else:
        pairs = image.reshape(height, width // 2, 2)
        packed = out[:, :line].reshape(height, width // 2, 3)
        packed[..., :2] = pairs >> 4
        packed[..., 2] = (pairs[..., 0] & 0xF) | (pairs[..., 1] & 0xF) << 4
    return out


class SyntheticSource:
    """A node that delivers a fixed image.

    Parameters
    ----------
    image
        The frame's pixels (``(height, width)``, values below ``2**bits``).
    fourcc
        The raw format it is delivered in.
    fps
        Frames a second (buffers are ready on that clock).
    path
        The name it answers to.
    pad
        Bytes of padding after each line.
    controls
        Its controls (IMX219-like by default).
    quantum
        Control id -> the step the driver rounds that control's values to (the value
        read back is the rounded one, as from a driver that adjusts to its hardware).
    crop
        Whether the driver crops (its bounds are the whole image).
    sizes
        Its modes' frame sizes (the image's size alone by default).
    """

    card = "imx219 (synthetic)"  # its controls are those of the IMX219 driver
    model = card

    def __init__(
        self,
        image: NDArray[np.uint16],
        *,
        fourcc: str = "pRAA",
        fps: float = 30.0,
        path: str = "synthetic:0",
        pad: int = 0,
        controls: tuple[ControlInfo, ...] = IMX219_CONTROLS,
        quantum: Mapping[int, int] | None = None,
        crop: bool = False,
        sizes: tuple[tuple[int, int], ...] = (),
    ) -> None:
        fmt = raw_format(fourcc)
        height, width = image.shape
        self.path = path
        self._native = fmt.bayer
        self._image, self._pad = image, pad
        full = Rect(0, 0, width, height)
        self._options = ShapeOptions(crop_bounds=full if crop else None, sizes=sizes)
        self._crop = full if crop else None
        self._deliver(fmt, image)
        self.period_s = 1.0 / fps
        self._controls = {c.id: c for c in controls}
        self._values = {c.id: c.default for c in controls}
        self._quantum = dict(quantum or {})
        # (monotonic s, control values from then on): what each due frame is taken with
        self._history: list[tuple[float, dict[int, int]]] = [(0.0, dict(self._values))]
        self.applied: OrderedDict[int, dict[int, int]] = OrderedDict()  # sequence -> values
        self._streaming = False
        self._sequence = 0
        self._next_s = 0.0
        self._busy_buffers: set[int] = set()  # filled or held by the consumer
        self._filled: list[Buffer] = []
        self._buffers = 0
        self._lock = threading.Lock()
        self.sim_gone = False
        self.sim_silent = False
        self.sim_busy = False
        self._drop_next = 0
        self.lost = 0  # frames lost for want of a free buffer (the reader fell behind)
        self._fail_next = False

    def _deliver(self, fmt: RawFormat, image: NDArray[np.uint16]) -> None:
        height, width = image.shape
        self.stream_format = StreamFormat(fmt, width, height, fmt.line_bytes(width) + self._pad)
        self.data = pack(image, fmt, stride=self.stream_format.stride).reshape(-1)

    # -- faults ----------------------------------------------------------------------------

    def sim_drop(self, frames: int) -> None:
        """The next ``frames`` frames are lost (the sequence skips them)."""
        self._drop_next += frames

    def sim_streaming_error(self) -> None:
        """The next dequeue fails as after the driver's fatal streaming error (EIO)."""
        self._fail_next = True

    # -- the FrameSource protocol ----------------------------------------------------------

    def start(self, buffers: int) -> None:
        if self.sim_gone:
            raise PortDisconnectedError(f"{self.path}: device gone")
        if self.sim_busy:
            raise DeviceBusyError(f"{self.path}: device busy: another program is streaming")
        self._buffers = max(buffers, 1)
        self._busy_buffers.clear()
        self._filled.clear()
        self._sequence = 0
        self._next_s = time.monotonic() + self.period_s
        self._streaming = True

    def dequeue(self, timeout_s: float) -> Buffer | None:
        deadline = time.monotonic() + timeout_s
        while True:
            if self.sim_gone:
                raise PortDisconnectedError(f"{self.path}: device gone (No such device)")
            if self._fail_next:
                self._fail_next = False
                raise OSError(5, "Input/output error")
            now = time.monotonic()
            self._fill(now)
            if self._filled:
                return self._filled.pop(0)
            if now >= deadline:
                return None
            wake = min(deadline, self._next_s) if self._streaming else deadline
            time.sleep(max(min(wake - now, 0.05), 0.0005))

    def _fill(self, now: float) -> None:
        """Every frame due by now goes into a queued buffer, or is lost if none is free."""
        while self._streaming and not self.sim_silent and now >= self._next_s:
            due_s = self._next_s
            timestamp_ns = round(due_s * 1e9)  # when the frame was due, as drivers stamp
            self._next_s += self.period_s
            if self._drop_next:
                self._sequence += self._drop_next
                self._drop_next = 0
            self._note_applied(self._sequence, due_s)
            free = [i for i in range(self._buffers) if i not in self._busy_buffers]
            if free:
                self._busy_buffers.add(free[0])
                self._filled.append(Buffer(free[0], self.data, self._sequence, timestamp_ns))
            else:  # without a free buffer the frame is lost: a gap
                self.lost += 1
            self._sequence += 1

    def _note_applied(self, sequence: int, due_s: float) -> None:
        """Keep the control values frame ``sequence``, due at ``due_s``, was taken with."""
        with self._lock:
            k = bisect.bisect_right([t for t, _ in self._history], due_s)
            self.applied[sequence] = self._history[k - 1][1]
            while len(self.applied) > APPLIED_FRAMES:
                self.applied.popitem(last=False)

    def requeue(self, buffer: Buffer) -> None:
        if self.sim_gone:
            raise PortDisconnectedError(f"{self.path}: device gone")
        self._busy_buffers.discard(buffer.index)

    def stop(self) -> None:
        self._streaming = False
        self._busy_buffers.clear()
        self._filled.clear()

    def close(self) -> None:
        self.stop()

    def shape_options(self) -> ShapeOptions:
        return self._options

    def shape(self) -> Shape:
        return Shape(self._crop, (self.stream_format.width, self.stream_format.height))

    def set_shape(self, shape: Shape) -> StreamFormat:
        if self._streaming:
            raise DeviceBusyError(f"{self.path}: the shape cannot change while streaming")
        bounds, fmt = self._options.crop_bounds, self.stream_format.format
        if bounds is not None and shape.crop is not None:
            c = shape.crop
            across = c.width > 0 and c.left >= 0 and c.left + c.width <= bounds.width
            down = c.height > 0 and c.top >= 0 and c.top + c.height <= bounds.height
            if not (across and down):
                raise ControlRefusedError("crop", c, f"inside {bounds} (the driver's bounds)")
            self._crop = c
            image = self._image[c.top : c.top + c.height, c.left : c.left + c.width]
        elif shape.size in self._options.sizes:
            width, height = shape.size
            image = self._image[:height, :width]
        else:
            raise ControlRefusedError("size", shape.size, f"one of {self._options.sizes}")
        line_pixels = self.stream_format.width + self._values.get(CID_HBLANK, 0)
        self._deliver(fmt, np.ascontiguousarray(image))
        if CID_HBLANK in self._values:  # the line keeps its length, as the IMX219's modes do
            blank = line_pixels - self.stream_format.width
            self._controls[CID_HBLANK] = replace(
                self._controls[CID_HBLANK], minimum=blank, maximum=blank, default=blank
            )
            self._values[CID_HBLANK] = blank
        return self.refresh_format()

    def refresh_format(self) -> StreamFormat:
        fmt = self.stream_format.format
        if self._native is not None:
            order = flipped_bayer(
                self._native,
                hflip=bool(self._values.get(CID_HFLIP)),
                vflip=bool(self._values.get(CID_VFLIP)),
            )
            fourcc = next(f.fourcc for f in _same_kind(fmt) if f.bayer == order)
            self.stream_format = StreamFormat(
                raw_format(fourcc),
                self.stream_format.width,
                self.stream_format.height,
                self.stream_format.stride,
            )
        return self.stream_format

    def controls(self) -> Mapping[int, ControlInfo]:
        return dict(self._controls)

    def get_controls(self, ids: list[int]) -> dict[int, int]:
        if self.sim_gone:
            raise PortDisconnectedError(f"{self.path}: device gone")
        with self._lock:
            return {i: self._values[i] for i in ids}

    def set_controls(self, values: Mapping[int, int]) -> None:
        with self._lock:
            for cid, value in values.items():
                info = self._controls[cid]
                if not info.minimum <= value <= info.maximum or info.read_only:
                    raise ControlRefusedError(
                        info.name, value, f"{info.minimum}..{info.maximum} (the driver's limits)"
                    )
            for cid, value in values.items():
                step = self._quantum.get(cid, 1)
                self._values[cid] = round(value / step) * step
            self._history.append((time.monotonic(), dict(self._values)))
            del self._history[:-APPLIED_FRAMES]


def _same_kind(fmt: RawFormat) -> list[RawFormat]:
    return [f for f in RAW_FORMATS.values() if f.bits == fmt.bits and f.packing is fmt.packing]
