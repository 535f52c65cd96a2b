"""A V4L2 capture node through linuxpy: formats, MMAP streaming, controls.

The only module that imports linuxpy (GPL-3.0-or-later, the optional ``v4l2`` extra of
elphel-camd): the rest of the image path sees a `elphel_camd.v4l2.source.FrameSource`.
Single-planar capture only (linuxpy has no multi-planar streaming). With a media
controller the sensor subdevice's format is set to the node's before streaming, and the
controls come from that subdevice when the node has none (`elphel_camd.v4l2.media`).
"""

from __future__ import annotations

import contextlib
import errno
import glob
import mmap
import os
import select
from collections.abc import Mapping
from typing import Any

from elphel_camd.errors import (
    CameraError,
    ControlRefusedError,
    DeviceBusyError,
    PortDisconnectedError,
    VideoNodeError,
)
from elphel_camd.v4l2.controls import PARAMETER_CONTROLS
from elphel_camd.v4l2.formats import RAW_BY_CODE, RAW_FORMATS, choose_format, fourcc_text
from elphel_camd.v4l2.media import SensorSubdev, open_sensor
from elphel_camd.v4l2.shape import Rect, Shape, ShapeOptions
from elphel_camd.v4l2.source import Buffer, ControlInfo, StreamFormat

try:
    from linuxpy.video import device as v4l2
    from linuxpy.video import raw
except ImportError as e:  # pragma: no cover - depends on the installation
    raise ImportError("the v4l2 board needs linuxpy: pip install 'elphel-camd[v4l2]'") from e

CAPTURE = raw.BufType.VIDEO_CAPTURE
MMAP = raw.Memory.MMAP
# Errors meaning the device itself is gone (unplugged, unbound, vivid's disconnect).
GONE = {errno.ENODEV, errno.ENXIO, errno.EPIPE}
_NUMERIC = {raw.CtrlType.INTEGER, raw.CtrlType.BOOLEAN, raw.CtrlType.INTEGER64}
# What a driver answers to a selection it does not have (no crop on this node or input).
_NO_SELECTION = {errno.ENOTTY, errno.EINVAL, errno.ENODATA}


def _present_nodes() -> str:
    return ", ".join(sorted(glob.glob("/dev/video*"))) or "none"


class VideoNode:
    """One V4L2 capture node, opened and set to a raw format.

    Parameters
    ----------
    path
        The node, e.g. ``/dev/video0``.
    fourcc, size
        Format and size to stream (defaults: see `elphel_camd.v4l2.formats.choose_format`).
    """

    def __init__(
        self, path: str, *, fourcc: str | None = None, size: tuple[int, int] | None = None
    ) -> None:
        self.path = path
        self._fd = self._open(path)
        self._maps: list[mmap.mmap] = []
        self._queries: dict[int, Any] = {}
        self.card = ""
        self.sensor: SensorSubdev | None = None
        try:
            self._check_capture()
            self.stream_format = self._set_format(fourcc, size)
            self.sensor = open_sensor(path)
            self._control_fd = self._choose_control_fd()
            self._options = self._read_shape_options()
            self._crop = self._selection(v4l2.SelectionTarget.CROP)
        except BaseException:
            self._close_fds()
            raise
        self.model = self.sensor.name if self.sensor is not None else self.card

    def _choose_control_fd(self) -> int:
        """The node's controls, or the sensor subdevice's when the node has none of ours."""
        if self.sensor is None:
            return self._fd
        own = {q.id for q in v4l2.iter_read_controls(self._fd)}
        return self._fd if own & PARAMETER_CONTROLS else self.sensor.fd

    def _close_fds(self) -> None:
        if self.sensor is not None:
            self.sensor.close()
            self.sensor = None
        os.close(self._fd)

    @staticmethod
    def _open(path: str) -> int:
        try:
            return os.open(path, os.O_RDWR | os.O_NONBLOCK)
        except FileNotFoundError:
            raise VideoNodeError(
                f"{path}: no such V4L2 node; nodes present: {_present_nodes()}"
            ) from None
        except OSError as e:
            raise VideoNodeError(f"{path}: cannot open: {e.strerror}") from e

    def _check_capture(self) -> None:
        caps = v4l2.read_capabilities(self._fd)
        self.card = caps.card.decode(errors="replace")
        flags = caps.device_caps or caps.capabilities
        if not flags & raw.Capability.VIDEO_CAPTURE:
            planar = " (it is multi-planar only, which linuxpy cannot stream)"
            extra = planar if flags & raw.Capability.VIDEO_CAPTURE_MPLANE else ""
            raise VideoNodeError(f"{self.path}: not a single-planar video capture node{extra}")
        if not flags & raw.Capability.STREAMING:
            raise VideoNodeError(f"{self.path}: the driver cannot stream (no MMAP streaming)")

    def offered(self) -> dict[str, list[tuple[int, int]]]:
        """Fourcc -> discrete frame sizes offered (empty for stepwise sizes)."""
        out: dict[str, list[tuple[int, int]]] = {}
        for fmt in v4l2.iter_read_formats(self._fd, CAPTURE):
            fourcc = fourcc_text(int(fmt.pixel_format))
            sizes = []
            for size in v4l2.iter_read_frame_sizes(self._fd, int(fmt.pixel_format)):
                if size.type == raw.Frmsizetypes.DISCRETE:
                    sizes.append((size.info.width, size.info.height))
            out[fourcc] = sizes
        return out

    def _current(self) -> Any:
        return v4l2.get_raw_format(self._fd, CAPTURE).fmt.pix

    def _set_format(self, fourcc: str | None, size: tuple[int, int] | None) -> StreamFormat:
        pix = self._current()
        current = (fourcc_text(pix.pixelformat), pix.width, pix.height)
        try:
            choice = choose_format(
                self.offered(), current=current, wanted_fourcc=fourcc, wanted_size=size
            )
        except ValueError as e:
            raise VideoNodeError(f"{self.path}: {e}") from e
        if current != (choice.format.fourcc, choice.width, choice.height):
            try:
                v4l2.set_format(
                    self._fd, CAPTURE, choice.width, choice.height, choice.format.fourcc
                )
            except OSError as e:
                raise self._busy_or(e, "setting the format") from e
        return self.refresh_format()

    def refresh_format(self) -> StreamFormat:
        pix = self._current()
        fmt = RAW_BY_CODE.get(pix.pixelformat)
        if fmt is None:
            raise VideoNodeError(
                f"{self.path}: the driver set format {fourcc_text(pix.pixelformat)!r}, not raw"
            )
        stride = pix.bytesperline or fmt.line_bytes(pix.width)
        self.stream_format = StreamFormat(fmt, pix.width, pix.height, stride)
        return self.stream_format

    def _busy_or(self, error: OSError, doing: str) -> VideoNodeError:
        if error.errno == errno.EBUSY:
            return DeviceBusyError(
                f"{self.path}: device busy while {doing}: another program is streaming "
                "from this node (stop it, e.g. a running v4l2-ctl, libcamera or camera app)"
            )
        return VideoNodeError(f"{self.path}: {doing} failed: {error.strerror}")

    # -- streaming -------------------------------------------------------------------------

    def start(self, buffers: int) -> None:
        if self.sensor is not None:
            self._follow_sensor(self.sensor.match(self.stream_format))
        try:
            v4l2.request_buffers(self._fd, CAPTURE, MMAP, buffers)
        except OSError as e:
            raise self._busy_or(e, "requesting buffers") from e
        self._maps = []
        index = 0  # the driver may grant more or fewer buffers than asked
        while True:
            try:
                buf = v4l2.query_buffer(self._fd, CAPTURE, MMAP, index)
            except OSError:
                break
            self._maps.append(v4l2.mem_map(self._fd, buf.length, buf.m.offset))
            v4l2.enqueue_buffer(self._fd, CAPTURE, MMAP, 0, index)
            index += 1
        try:
            v4l2.stream_on(self._fd, CAPTURE)
        except OSError as e:
            self.stop()
            if e.errno in (errno.EINVAL, errno.EPIPE):
                raise VideoNodeError(self._pipeline_hint(e)) from e
            raise self._busy_or(e, "starting the stream") from e

    def _follow_sensor(self, order: str | None) -> None:
        """Give the node the Bayer order the sensor sends (its flips decide it)."""
        fmt = self.stream_format
        if order == fmt.format.bayer:
            return
        fourcc = next(
            f.fourcc
            for f in RAW_FORMATS.values()
            if (f.bits, f.packing, f.bayer) == (fmt.format.bits, fmt.format.packing, order)
        )
        try:
            v4l2.set_format(self._fd, CAPTURE, fmt.width, fmt.height, fourcc)
        except OSError as e:
            raise self._busy_or(e, f"setting the sensor's Bayer order {fourcc!r}") from e
        self.refresh_format()

    def _pipeline_hint(self, error: OSError) -> str:
        """Why STREAMON fails on a media-controller camera, and the two ways out."""
        fmt = self.stream_format
        if self.sensor is not None:
            return (
                f"{self.path}: starting the stream failed ({error.strerror}) although the "
                f"sensor {self.sensor.name!r} on {self.sensor.path} was set to the node's "
                f"format ({fmt.width}x{fmt.height} {fmt.format.fourcc!r}): another entity "
                f"of {self.sensor.media} ({self.sensor.driver}) may need it too; "
                f"{self.sensor.hint(fmt)}"
            )
        return (
            f"{self.path}: starting the stream failed ({error.strerror}). With a media "
            "controller the sensor subdevice's format must match the node's "
            f"({fmt.width}x{fmt.height} {fmt.format.fourcc!r}): set it with media-ctl, e.g. "
            "media-ctl -d /dev/media0 --set-v4l2 \"'<sensor subdev>':0[fmt:<bus code>/"
            f'{fmt.width}x{fmt.height}]", or load the camera overlay with '
            "media-controller=0 (e.g. dtoverlay=imx219,media-controller=0) so the video "
            "node carries the format and the controls"
        )

    def dequeue(self, timeout_s: float) -> Buffer | None:
        try:
            ready, _, failed = select.select([self._fd], [], [self._fd], timeout_s)
            if not ready and not failed:
                return None
            buf = v4l2.dequeue_buffer(self._fd, CAPTURE, MMAP)
        except OSError as e:
            if e.errno == errno.EAGAIN:
                return None
            if e.errno in GONE:
                raise PortDisconnectedError(f"{self.path}: device gone ({e.strerror})") from e
            raise
        timestamp_ns = buf.timestamp.secs * 1_000_000_000 + buf.timestamp.usecs * 1000
        return Buffer(
            index=buf.index,
            data=self._maps[buf.index],
            sequence=buf.sequence,
            timestamp_ns=timestamp_ns,
            error=bool(buf.flags & raw.BufferFlag.ERROR),
        )

    def requeue(self, buffer: Buffer) -> None:
        try:
            v4l2.enqueue_buffer(self._fd, CAPTURE, MMAP, 0, buffer.index)
        except OSError as e:
            if e.errno in GONE:
                raise PortDisconnectedError(f"{self.path}: device gone ({e.strerror})") from e
            raise

    def stop(self) -> None:
        for call in (v4l2.stream_off, lambda fd, t: v4l2.free_buffers(fd, t, MMAP)):
            with contextlib.suppress(OSError):  # a vanished device refuses both
                call(self._fd, CAPTURE)
        self._unmap()

    def _unmap(self) -> None:
        for m in self._maps:
            m.close()
        self._maps = []

    def close(self) -> None:
        self.stop()
        self._close_fds()

    # -- shape -----------------------------------------------------------------------------

    def _selection(self, target: Any) -> Rect | None:
        """A selection rectangle of the capture queue, or None if the driver has none."""
        try:
            r = v4l2.get_selection(self._fd, CAPTURE, target)
        except OSError as e:
            if e.errno in _NO_SELECTION:
                return None
            raise
        return Rect(r.left, r.top, r.width, r.height)

    def _read_shape_options(self) -> ShapeOptions:
        bounds = self._selection(v4l2.SelectionTarget.CROP_BOUNDS)
        if bounds is not None and self._selection(v4l2.SelectionTarget.CROP) is None:
            bounds = None
        sizes = self.offered().get(self.stream_format.format.fourcc, [])
        return ShapeOptions(crop_bounds=bounds, sizes=tuple(sizes))

    def shape_options(self) -> ShapeOptions:
        return self._options

    def shape(self) -> Shape:
        return Shape(self._crop, (self.stream_format.width, self.stream_format.height))

    def set_shape(self, shape: Shape) -> StreamFormat:
        if shape.crop is not None and shape.crop != self._crop:
            c = shape.crop
            try:
                v4l2.set_selection(
                    self._fd,
                    CAPTURE,
                    v4l2.SelectionTarget.CROP,
                    v4l2.Rect(c.left, c.top, c.width, c.height),
                )
            except OSError as e:
                raise self._shape_refused(
                    e, f"crop {c.width}x{c.height} at ({c.left}, {c.top})"
                ) from e
            self._crop = self._selection(v4l2.SelectionTarget.CROP)
        pix = self._current()
        if (pix.width, pix.height) != shape.size:
            width, height = shape.size
            try:
                v4l2.set_format(self._fd, CAPTURE, width, height, fourcc_text(pix.pixelformat))
            except OSError as e:
                raise self._shape_refused(e, f"frame size {width}x{height}") from e
        return self.refresh_format()

    def _shape_refused(self, error: OSError, asked: str) -> CameraError:
        if error.errno in GONE:
            return PortDisconnectedError(f"{self.path}: device gone ({error.strerror})")
        if error.errno == errno.EBUSY:
            return self._busy_or(error, f"setting the {asked}")
        return ControlRefusedError(
            "WOI_WIDTH", asked, f"what the driver takes ({error.strerror}): {self._options}"
        )

    # -- controls --------------------------------------------------------------------------

    def controls(self) -> Mapping[int, ControlInfo]:
        if not self._queries:
            for q in v4l2.iter_read_controls(self._control_fd):
                if q.type in _NUMERIC and not q.flags & raw.ControlFlag.DISABLED:
                    self._queries[q.id] = q
        return {i: _info(q) for i, q in self._queries.items()}

    def get_controls(self, ids: list[int]) -> dict[int, int]:
        self.controls()
        values = v4l2.get_controls_values(self._control_fd, [self._queries[i] for i in ids])
        return {i: int(v) for i, v in zip(ids, values, strict=True)}

    def set_controls(self, values: Mapping[int, int]) -> None:
        self.controls()
        pairs = [(self._queries[i], int(v)) for i, v in values.items()]
        try:
            v4l2.set_controls_values(self._control_fd, pairs)
        except OSError as e:
            if e.errno in GONE:
                raise PortDisconnectedError(f"{self.path}: device gone ({e.strerror})") from e
            if e.errno == errno.EBUSY:
                raise self._busy_or(e, "setting controls") from e
            refused = ", ".join(
                f"{q.name.decode()}={v} (driver allows {q.minimum}..{q.maximum} step {q.step})"
                for q, v in pairs
            )
            raise ControlRefusedError(
                "controls", refused, f"the driver's limits: {e.strerror}"
            ) from e


def _info(q: Any) -> ControlInfo:
    return ControlInfo(
        id=q.id,
        name=q.name.decode(),
        minimum=q.minimum,
        maximum=q.maximum,
        step=q.step,
        default=q.default_value,
        read_only=bool(q.flags & raw.ControlFlag.READ_ONLY),
        inactive=bool(q.flags & raw.ControlFlag.INACTIVE),
    )
