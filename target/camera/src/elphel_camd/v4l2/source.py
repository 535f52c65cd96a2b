"""What the V4L2 board reads frames and controls from: the `FrameSource` protocol.

`elphel_camd.v4l2.node.VideoNode` is the real one (a V4L2 capture node through linuxpy);
`elphel_camd.v4l2.synthetic.SyntheticSource` makes frames in memory for tests and
benchmarks on machines without a camera. The board never knows which it has.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol

from elphel_camd.v4l2.formats import RawFormat
from elphel_camd.v4l2.shape import Shape, ShapeOptions
from elphel_camd.v4l2.unpack import FrameData


@dataclass(frozen=True)
class StreamFormat:
    """The format a node streams in: pixel format, size and line stride."""

    format: RawFormat
    width: int
    height: int
    stride: int

    @property
    def frame_bytes(self) -> int:
        """Bytes of one frame's lines (stride included)."""
        return self.stride * self.height


@dataclass(frozen=True)
class Buffer:
    """One filled buffer, taken from the driver until `FrameSource.requeue`.

    ``sequence`` is the driver's frame counter (gaps are dropped frames), ``timestamp_ns``
    the driver's capture time (CLOCK_MONOTONIC for most capture drivers), ``error`` the
    driver's flag that the data may be corrupt.
    """

    index: int
    data: FrameData
    sequence: int
    timestamp_ns: int
    error: bool = False


@dataclass(frozen=True)
class ControlInfo:
    """One integer or boolean control as the driver describes it."""

    id: int
    name: str
    minimum: int
    maximum: int
    step: int
    default: int
    read_only: bool = False
    inactive: bool = False


class FrameSource(Protocol):
    """A capture node, or something that behaves like one."""

    path: str
    card: str  # the driver's name for the device (QUERYCAP's card)
    # The sensor's kernel driver as the media controller names it ("imx219 10-0010"),
    # else the card: its first word picks the gain laws.
    model: str
    stream_format: StreamFormat

    def start(self, buffers: int) -> None:
        """Allocate ``buffers`` buffers, queue them all and start streaming."""
        ...

    def dequeue(self, timeout_s: float) -> Buffer | None:
        """The next filled buffer, or None after ``timeout_s`` without one.

        Raises `elphel_camd.v4l2.errors.PortDisconnectedError` when the device is gone
        and OSError when streaming failed (the caller restarts it).
        """
        ...

    def requeue(self, buffer: Buffer) -> None:
        """Give a buffer back to the driver."""
        ...

    def stop(self) -> None:
        """Stop streaming and free the buffers."""
        ...

    def controls(self) -> Mapping[int, ControlInfo]:
        """The integer and boolean controls, by V4L2 control id."""
        ...

    def get_controls(self, ids: list[int]) -> dict[int, int]:
        """Current values of controls, read from the driver now."""
        ...

    def set_controls(self, values: Mapping[int, int]) -> None:
        """Set controls together (ControlRefusedError naming the driver's limits)."""
        ...

    def refresh_format(self) -> StreamFormat:
        """Read the format back from the driver (a flip may change the Bayer order)."""
        ...

    def shape_options(self) -> ShapeOptions:
        """How the node's shape can change: the driver's crop bounds, or its sizes."""
        ...

    def shape(self) -> Shape:
        """The crop (when the driver crops) and the frame size the node is set to."""
        ...

    def set_shape(self, shape: Shape) -> StreamFormat:
        """With the stream stopped: crop, then the frame size; the format read back.

        Raises ControlRefusedError when the driver refuses the crop or the size.
        """
        ...

    def close(self) -> None:
        """Release the node."""
        ...
