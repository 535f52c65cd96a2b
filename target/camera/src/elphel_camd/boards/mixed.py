"""The ``mixed`` board: ports of different kinds side by side, listed in the config file.

Each entry of the config file's ``ports`` list is one port, numbered in order from 0,
with its frame source and its control path:

* ``{"video": "/dev/video0"}``: a V4L2 capture node (`elphel_camd.boards.v4l2`), with
  optional ``format``, ``size``, ``model`` (the kernel driver, for its gain laws), ``bus``
  (an I2C bus when the project's own driver programs the sensor; without it the node's
  controls carry the parameters), ``ring_frames``, ``buffers`` and ``timeout_periods``;
* ``{"vospi": "/dev/spidev0.0"}``: a FLIR Lepton 3.x (`elphel_camd.boards.lepton`), with
  optional ``bus`` (its CCI), ``spi_clock_hz``, ``telemetry_location``, ``replay_fps``
  and ``capture_timeout_s``.

Every port is checked before any device is opened; an error names the port, the field
and what is allowed. The board has a capability only when every port has it: a Lepton
has no frame syncs, so with one on the board changes apply at once (no ``frame=`` or
``ahead=``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any, Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from elphel_camd.boards.base import Frame, FrameSync
from elphel_camd.boards.lepton import LeptonBoard
from elphel_camd.boards.v4l2 import EventSink, SourceFactory, V4L2Board, open_node
from elphel_camd.errors import ConfigError, PortError
from elphel_camd.i2c.bus import I2CBus
from elphel_camd.sensors.base import SensorDriver
from elphel_camd.vospi.frame_source import LEPTON_UNIQUE_FPS
from elphel_camd.vospi.sources import MAX_CLOCK_HZ, MIN_CLOCK_HZ, ByteSource

FRAME_SOURCES = ("video", "vospi")


class VideoPort(BaseModel):
    """A V4L2 port of the config file: a `V4L2Port` and its `V4L2Board` options."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    video: str = Field(min_length=1, description="the capture node, e.g. /dev/video0")
    format: str | None = Field(None, description="fourcc to stream, e.g. pRAA")
    size: str | None = Field(None, pattern=r"^\d+x\d+$", description="WIDTHxHEIGHT to stream")
    bus: str | None = Field(None, description="I2C bus of a sensor the project's driver runs")
    model: str | None = Field(None, description="kernel driver of the sensor, e.g. imx219")
    ring_frames: int = Field(8, ge=1, le=1024, description="frames kept for ?frame=N, bursts")
    buffers: int = Field(4, ge=2, le=32, description="driver buffers of the node")
    timeout_periods: int = Field(5, ge=1, le=1000, description="frame periods before a 504")


class LeptonPort(BaseModel):
    """A Lepton port of the config file (arguments of `LeptonBoard`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    vospi: str = Field(min_length=1, description="spidev node, or a file or FIFO of VoSPI")
    bus: str | None = Field(None, description="I2C bus of the Lepton's CCI")
    spi_clock_hz: int = Field(MAX_CLOCK_HZ, ge=MIN_CLOCK_HZ, le=MAX_CLOCK_HZ)
    telemetry_location: Literal["footer", "header"] = "footer"
    replay_fps: float = Field(LEPTON_UNIQUE_FPS, ge=0, allow_inf_nan=False)
    capture_timeout_s: float = Field(2.0, gt=0, allow_inf_nan=False)


PortConfig = VideoPort | LeptonPort


def port_config(port: int, entry: Any) -> PortConfig:
    """One entry of ``ports``, checked (ConfigError naming the port and the field)."""
    if not isinstance(entry, Mapping):
        raise ConfigError(f"ports[{port}]: a JSON object is needed, not {type(entry).__name__}")
    sources = [key for key in FRAME_SOURCES if key in entry]
    if len(sources) != 1:
        got = " and ".join(sources) if sources else "neither"
        raise ConfigError(
            f"ports[{port}]: give one frame source, video (a V4L2 capture node) or vospi "
            f"(a Lepton's spidev node, file or FIFO); got {got}"
        )
    kind: type[PortConfig] = VideoPort if sources[0] == "video" else LeptonPort
    try:
        return kind.model_validate(dict(entry))
    except ValidationError as e:
        problems = "; ".join(
            f"{'.'.join(str(x) for x in err['loc']) or 'entry'}: {err['msg']}" for err in e.errors()
        )
        raise ConfigError(f"ports[{port}] ({sources[0]}): {problems}") from None


class PortBoard(Protocol):
    """What the mixed board needs of each board it is built from."""

    capabilities: frozenset[str]

    def buses(self) -> Mapping[int, I2CBus]: ...

    def sensors(self) -> Mapping[int, SensorDriver]: ...

    def on_frame_sync(self, callback: FrameSync) -> None: ...

    def program(self, port: int, function: str, state: Mapping[str, int]) -> None: ...

    def capture(self, port: int, *, frame: int | None = None, timeout_s: float = 10.0) -> Frame: ...

    def port_status(self, port: int) -> dict[str, Any]: ...

    def close(self) -> None: ...


VoSPIOpener = Callable[[LeptonPort], ByteSource | None]


def open_port(
    port: int, config: PortConfig, open_video: SourceFactory, open_vospi: VoSPIOpener
) -> PortBoard:
    """The one-port board of a checked port entry (its devices opened)."""
    if isinstance(config, VideoPort):
        board_options = {"ring_frames", "buffers", "timeout_periods"}
        return V4L2Board(
            ports=[config.model_dump(exclude=board_options)],
            open_source=open_video,
            first_port=port,
            **config.model_dump(include=board_options),
        )
    options = config.model_dump(exclude={"vospi", "bus"})
    return LeptonBoard(
        config.vospi,
        [config.bus] if config.bus else None,
        byte_source=open_vospi(config),
        port=port,
        **options,
    )


class MixedBoard:
    """Ports of different kinds (V4L2 nodes, Lepton VoSPI streams) in one daemon.

    Parameters
    ----------
    ports
        The config file's ``ports``: one entry a port, ``video`` or ``vospi`` (see the
        module docstring).
    open_video
        Opens a V4L2 port's node (tests pass synthetic sources).
    open_vospi
        A byte source for a Lepton port instead of opening its ``vospi`` path (a simulated
        Lepton); None opens the path.
    """

    name = "mixed"

    def __init__(
        self,
        ports: Sequence[Mapping[str, Any]] = (),
        *,
        open_video: SourceFactory = open_node,
        open_vospi: VoSPIOpener = lambda config: None,
    ) -> None:
        if not ports:
            raise ConfigError(
                'the mixed board needs "ports" in the config file, one entry a port, e.g. '
                '[{"video": "/dev/video0"}, {"vospi": "/dev/spidev0.0"}]'
            )
        configs = [port_config(n, entry) for n, entry in enumerate(ports)]
        self.boards: dict[int, PortBoard] = {}
        try:
            for n, config in enumerate(configs):
                self.boards[n] = open_port(n, config, open_video, open_vospi)
        except BaseException:
            self.close()
            raise
        self.capabilities: frozenset[str] = frozenset.intersection(
            *(b.capabilities for b in self.boards.values())
        )

    def _board(self, port: int) -> PortBoard:
        board = self.boards.get(port)
        if board is None:
            raise PortError(f"port {port} does not exist; ports: {sorted(self.boards)}")
        return board

    # -- the Board protocol ----------------------------------------------------------------

    def buses(self) -> Mapping[int, I2CBus]:
        """The I2C buses of the ports whose sensor is found on one."""
        return {p: bus for b in self.boards.values() for p, bus in b.buses().items()}

    def sensors(self) -> Mapping[int, SensorDriver]:
        """The drivers of the ports the boards drive themselves (V4L2 controls, no CCI)."""
        return {p: d for b in self.boards.values() for p, d in b.sensors().items()}

    def on_frame_sync(self, callback: FrameSync) -> None:
        for board in self.boards.values():
            board.on_frame_sync(callback)

    def on_event(self, sink: EventSink) -> None:
        """Pass on the ports' own events (V4L2: dropped frames, port states)."""
        for board in self.boards.values():
            on_event = getattr(board, "on_event", None)
            if on_event is not None:
                on_event(sink)

    def program(self, port: int, function: str, state: Mapping[str, int]) -> None:
        self._board(port).program(port, function, state)

    def capture(self, port: int, *, frame: int | None = None, timeout_s: float = 10.0) -> Frame:
        return self._board(port).capture(port, frame=frame, timeout_s=timeout_s)

    def port_status(self, port: int) -> dict[str, Any]:
        """The port's frame stream, with the kind of its frame source."""
        board = self._board(port)
        kind = "vospi" if isinstance(board, LeptonBoard) else "video"
        return {**board.port_status(port), "source": kind}

    def close(self) -> None:
        for board in self.boards.values():
            board.close()
