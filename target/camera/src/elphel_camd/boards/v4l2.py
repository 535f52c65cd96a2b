"""The ``v4l2`` board: frames from V4L2 capture nodes, one sensor port per node.

Each port streams its node (MMAP buffers) into a ring of recent frames in a thread of its
own (`elphel_camd.v4l2.stream.PortStream`). A sensor a kernel driver owns is driven
through the node's controls (`elphel_camd.v4l2.sensor.V4L2Sensor`); a sensor no kernel
driver owns is paired with an I2C bus in the configuration and driven by the project's
own driver found on that bus, while its frames still come from the node.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

from elphel_camd.boards.base import Frame, FrameSync
from elphel_camd.errors import ConfigError, PortDisconnectedError, PortError
from elphel_camd.i2c.bus import I2CBus, open_bus
from elphel_camd.sensors.base import SensorDriver
from elphel_camd.v4l2.ring import FrameRing
from elphel_camd.v4l2.sensor import V4L2Sensor
from elphel_camd.v4l2.source import FrameSource
from elphel_camd.v4l2.stream import PortStream

log = logging.getLogger(__name__)

EventSink = Callable[[str, dict[str, Any]], None]
FrameLost = Callable[[int, int], None]  # (port, frame) of a frame the driver lost


@dataclass(frozen=True)
class V4L2Port:
    """One port of the board as configured.

    Parameters
    ----------
    video
        The capture node, e.g. ``/dev/video0``.
    format
        Fourcc to stream (default: the node's current raw format, else its raw format
        with the most bits at the largest size).
    size
        ``"WIDTHxHEIGHT"`` to stream (default: the current or largest size).
    bus
        An I2C bus URL when the project's own driver programs the sensor (no kernel
        driver owns it); without one the node's controls carry the parameters.
    model
        The kernel driver's name for its gain laws (default: the sensor subdevice's name
        with a media controller, else the node's card name).
    """

    video: str
    format: str | None = None
    size: str | None = None
    bus: str | None = None
    model: str | None = None

    def size_tuple(self) -> tuple[int, int] | None:
        if self.size is None:
            return None
        try:
            width, height = (int(v) for v in self.size.lower().split("x"))
        except ValueError:
            raise ConfigError(f"{self.video}: size {self.size!r}; allowed: WIDTHxHEIGHT") from None
        return width, height


SourceFactory = Callable[[V4L2Port], FrameSource]


def open_node(port: V4L2Port) -> FrameSource:
    """The real node of a port (linuxpy, imported only here)."""
    from elphel_camd.v4l2.node import VideoNode  # the optional v4l2 extra

    return VideoNode(port.video, fourcc=port.format, size=port.size_tuple())


class V4L2Board:
    """Frames from V4L2 nodes, one port each.

    Parameters
    ----------
    video
        Capture nodes, one port each (``--video``).
    ports
        Port settings (`V4L2Port` fields), from the config file; ``video`` ports follow.
    bus_urls
        With ``video``: the I2C bus of each node's sensor, in the same order (``--bus``),
        for sensors the project's own drivers program.
    sensor
        With ``video``: the kernel driver of the sensors (``--sensor``), for gain laws.
    ring_frames
        Frames kept per port for ``?frame=N`` and bursts.
    buffers
        Driver buffers per node.
    timeout_periods
        Frame periods without a frame before a capture gives up (504).
    open_source
        Opens a port's node (tests and benchmarks pass synthetic sources).
    first_port
        The number of the first port (a board of several kinds of port,
        `elphel_camd.boards.mixed`).
    """

    name = "v4l2"
    capabilities: frozenset[str] = frozenset({"frames", "capture"})

    def __init__(
        self,
        video: Sequence[str] = (),
        *,
        ports: Sequence[Mapping[str, Any]] = (),
        bus_urls: Sequence[str] = (),
        sensor: str | None = None,
        ring_frames: int = 8,
        buffers: int = 4,
        timeout_periods: int = 5,
        open_source: SourceFactory = open_node,
        first_port: int = 0,
    ) -> None:
        if bus_urls and len(bus_urls) != len(video):
            raise ConfigError(
                f"{len(bus_urls)} --bus for {len(video)} --video: give one bus per node "
                "(its sensor's) or none"
            )
        buses: list[str | None] = [*bus_urls] if bus_urls else [None] * len(video)
        specs = [V4L2Port(**p) for p in ports] + [
            V4L2Port(v, bus=b, model=sensor) for v, b in zip(video, buses, strict=True)
        ]
        if not specs:
            raise ConfigError("the v4l2 board needs at least one node (e.g. --video /dev/video0)")
        self.ports = dict(enumerate(specs, start=first_port))
        self.timeout_periods = timeout_periods
        self._subscribers: list[FrameSync] = []
        self._lost_subscribers: list[FrameLost] = []
        self._event_sinks: list[EventSink] = []
        self._buses: dict[int, I2CBus] = {}
        self._sensors: dict[int, V4L2Sensor] = {}
        self.streams: dict[int, PortStream] = {}
        try:
            for port, spec in self.ports.items():
                self._open_port(port, spec, open_source, ring_frames, buffers)
        except BaseException:
            self.close()
            raise

    def _open_port(
        self, port: int, spec: V4L2Port, opener: SourceFactory, ring_frames: int, buffers: int
    ) -> None:
        source = opener(spec)
        stream = PortStream(
            port,
            source,
            opener=lambda: opener(spec),
            ring=FrameRing(ring_frames),
            buffers=buffers,
            on_frame=self._on_frame,
            on_event=self._on_event,
            on_lost=self._on_lost,
        )
        self.streams[port] = stream
        if spec.bus is not None:
            self._buses[port] = open_bus(spec.bus)
        else:
            self._sensors[port] = V4L2Sensor(
                lambda: stream.source,
                model=spec.model or source.model,
                period_s=lambda: stream.period_ns / 1e9,
                reshape=stream.reshape,
            )
        stream.start()

    # -- the Board protocol ----------------------------------------------------------------

    def buses(self) -> Mapping[int, I2CBus]:
        """The I2C buses of ports whose sensor the project's own driver programs."""
        return self._buses

    def sensors(self) -> Mapping[int, SensorDriver]:
        """Drivers of the ports whose sensor a kernel driver owns (through the controls)."""
        return self._sensors

    def on_frame_sync(self, callback: FrameSync) -> None:
        self._subscribers.append(callback)

    def on_frame_lost(self, callback: FrameLost) -> None:
        """Call ``callback(port, frame)`` for the last frame of a gap the driver left.

        The frame sync it never had: a parameter schedule moves on with it, so a window
        due at the lost frame's successor is set before that frame is taken.
        """
        self._lost_subscribers.append(callback)

    def _on_lost(self, port: int, frame: int) -> None:
        for callback in self._lost_subscribers:
            self._guarded(port, frame, partial(callback, port, frame))

    def on_event(self, sink: EventSink) -> None:
        """Call ``sink(kind, payload)`` for dropped frames, port states and stream errors."""
        self._event_sinks.append(sink)

    def program(self, port: int, function: str, state: Mapping[str, int]) -> None:
        """Nothing beyond the sensor to program: no FPGA."""

    def _on_frame(self, port: int, frame: int, timestamp_ns: int) -> None:
        sensor = self._sensors.get(port)
        if sensor is not None:
            sensor.record(frame, timestamp_ns)
        for callback in self._subscribers:
            self._guarded(port, frame, partial(callback, port, frame, timestamp_ns))

    def _guarded(self, port: int, frame: int, call: Callable[[], None]) -> None:
        """Run a subscriber; a failure is logged and reported, and the stream goes on."""
        try:
            call()
        except Exception as e:
            log.exception("port %d: frame %d: a frame-sync subscriber failed", port, frame)
            self._on_event(
                "error",
                {
                    "port": port,
                    "frame": frame,
                    "error": "frame_sync",
                    "detail": f"port {port}: handling frame {frame} failed: {e}",
                },
            )

    def _on_event(self, kind: str, payload: dict[str, Any]) -> None:
        for sink in self._event_sinks:
            sink(kind, payload)

    def _stream(self, port: int) -> PortStream:
        stream = self.streams.get(port)
        if stream is None:
            raise PortError(f"port {port} does not exist; ports: {sorted(self.streams)}")
        return stream

    def port_status(self, port: int) -> dict[str, Any]:
        """The port's stream: state, node, format, frames, drops, restarts."""
        stream = self._stream(port)
        fmt = stream.source.stream_format
        return {
            "state": stream.state,
            **({"detail": stream.detail} if stream.detail else {}),
            "node": stream.source.path,
            "format": fmt.format.fourcc,
            "width": fmt.width,
            "height": fmt.height,
            "frames": stream.frames,
            "dropped": stream.drops,
            "restarts": stream.restarts,
        }

    def capture(self, port: int, *, frame: int | None = None, timeout_s: float = 10.0) -> Frame:
        """The next frame of a port, or frame ``frame`` from its ring.

        Raises PortDisconnectedError while the node is gone, FrameNotAvailableError for a
        frame no longer held, TimeoutError when no frame came for `timeout_periods` frame
        periods (or ``timeout_s``).
        """
        stream = self._stream(port)
        wanted = stream.ring.newest + 1 if frame is None else frame
        deadline = time.monotonic() + timeout_s
        while stream.ring.newest < wanted:
            self._check_connected(stream)
            waited_from = stream.ring.newest
            patience = self._patience_s(stream, deadline)
            if not stream.ring.wait_newer(waited_from, patience):
                self._check_connected(stream)
                raise TimeoutError(self._silence(stream, patience))
        if frame is None:  # the next frame the driver delivered (a lost one has no slot)
            wanted = min((f for f in stream.ring.frames() if f >= wanted), default=wanted)
        got = stream.ring.get(wanted)
        sensor = self._sensors.get(port)
        if sensor is not None:  # its metadata may be asked for before the stream noted it
            sensor.note_frame(got.frame, got.timestamp_ns)
        return Frame(image=got.image, frame=got.frame, timestamp_ns=got.timestamp_ns)

    def _patience_s(self, stream: PortStream, deadline: float) -> float:
        left = max(deadline - time.monotonic(), 0.0)
        if stream.period_ns <= 0:
            return left
        return min(left, max(self.timeout_periods * stream.period_ns / 1e9, 0.2))

    def _silence(self, stream: PortStream, waited_s: float) -> str:
        period = f"{stream.period_ns / 1e6:.1f} ms" if stream.period_ns else "unknown"
        return (
            f"port {stream.port}: no frame from {stream.source.path} for {waited_s:.2f} s "
            f"({self.timeout_periods} frame periods of {period}); last frame {stream.last_frame}"
        )

    @staticmethod
    def _check_connected(stream: PortStream) -> None:
        if stream.state == "disconnected":
            raise PortDisconnectedError(
                f"port {stream.port}: {stream.source.path} is disconnected ({stream.detail}); "
                "the port reconnects when the node returns"
            )

    def close(self) -> None:
        for stream in self.streams.values():
            stream.close()
        for bus in self._buses.values():
            close = getattr(bus, "close", None)
            if close is not None:
                close()
