"""The ``lepton`` board: one FLIR Lepton 3.x, frames over VoSPI, control over its CCI.

Frames come from a `LeptonFrameSource` (a spidev node, or a file or FIFO with the same
bytes); the CCI, when an I2C bus is given, is the `Lepton35` driver the camera service
finds on that bus. Without a bus the port still captures: its driver is
`LeptonWithoutCCI`, whose parameters are the Lepton's fixed ones.

Each captured frame's metadata carries the decoded telemetry rows (when telemetry is on)
and the unit of its pixels: ``centikelvin`` or ``decikelvin`` for TLinear (at 0.01 K or
0.1 K a count), ``counts`` for raw 14-bit flux.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any, ClassVar

from elphel_camd.boards.base import Frame, FrameSync
from elphel_camd.errors import FrameNotAvailableError, I2CError, PortError, UnsupportedError
from elphel_camd.i2c.bus import I2CBus, open_bus
from elphel_camd.sensors.base import SensorDriver
from elphel_camd.sensors.lepton35 import Lepton35, LeptonParameters
from elphel_camd.vospi import telemetry as tm
from elphel_camd.vospi.frame_source import LEPTON_UNIQUE_FPS, PROBE_TIMEOUT_S, LeptonFrameSource
from elphel_camd.vospi.reader import VoSPIFrame
from elphel_camd.vospi.sources import MAX_CLOCK_HZ, ByteSource

log = logging.getLogger(__name__)

TELEMETRY_LOCATIONS = {"header": tm.HEADER, "footer": tm.FOOTER}
UNITS_K = {0.01: "centikelvin", 0.1: "decikelvin"}


class LeptonWithoutCCI(LeptonParameters, SensorDriver):
    """A Lepton reached by VoSPI only: its fixed parameters, nothing to set.

    Without the CCI there is no chip to ask: `read_chip_id` is 0 and `identity` says
    ``"cci": false``.
    """

    model = Lepton35.model
    i2c_address = Lepton35.i2c_address
    sensor_code = Lepton35.sensor_code
    bayer = None
    bits = Lepton35.bits
    ahead = Lepton35.ahead
    writable: ClassVar[frozenset[str]] = frozenset()

    @classmethod
    def probe(cls, bus: I2CBus, *, bus_name: str) -> SensorDriver | None:
        """Never found on a bus: the board makes one when it has no CCI."""
        return None

    def read_chip_id(self) -> int:
        return 0

    def identity(self) -> dict[str, Any]:
        return {**super().identity(), "chip_id": None, "cci": False}

    def init(self) -> None:
        """Nothing to initialise without the CCI."""

    def program(self, function: str, state: Mapping[str, int]) -> list[str]:
        return []

    def check_writable(self, names: Mapping[str, int]) -> None:
        if names:
            raise UnsupportedError(
                f"{self.model} without its CCI cannot set {', '.join(sorted(names))}: "
                "start elphel-camd with --bus /dev/i2c-N (the Lepton's I2C bus)"
            )


class LeptonBoard:
    """One Lepton 3.x on one port (0 unless told): VoSPI frames, and the CCI when a bus is given.

    Parameters
    ----------
    vospi
        The spidev node, or a file or FIFO carrying VoSPI bytes.
    bus_urls
        At most one I2C bus URL: the Lepton's CCI.
    spi_clock_hz
        SPI clock for a spidev node (9..20 MHz).
    telemetry_location
        ``footer`` (the power-on default, and what the driver sets) or ``header``.
    byte_source
        A byte source to read instead of opening ``vospi`` (a simulated Lepton).
    bus
        An open I2C bus instead of ``bus_urls`` (a simulated CCI).
    replay_fps
        Frames a second at which a recording (a regular file) is replayed; 0: at once.
    capture_timeout_s
        How long a capture waits for a frame before it fails (504).
    port
        The port's number (a board of several ports, `elphel_camd.boards.mixed`).
    probe_timeout_s
        How long the start waits for a first good packet, to refuse a stream that is not
        VoSPI at once (`LeptonFrameSource.open`); 0 starts without waiting.
    """

    name = "lepton"
    capabilities: frozenset[str] = frozenset({"capture"})

    def __init__(
        self,
        vospi: str,
        bus_urls: list[str] | None = None,
        *,
        spi_clock_hz: int = MAX_CLOCK_HZ,
        telemetry_location: str = "footer",
        byte_source: ByteSource | None = None,
        bus: I2CBus | None = None,
        replay_fps: float = LEPTON_UNIQUE_FPS,
        capture_timeout_s: float = 2.0,
        port: int = 0,
        probe_timeout_s: float = PROBE_TIMEOUT_S,
    ) -> None:
        if len(bus_urls or []) > 1:
            raise ValueError(f"the lepton board takes one I2C bus (its CCI); got {bus_urls}")
        if telemetry_location not in TELEMETRY_LOCATIONS:
            raise ValueError(f"telemetry_location={telemetry_location!r}; allowed: header, footer")
        self.port = port
        self._bus = open_bus(bus_urls[0]) if bus_urls else bus
        self._subscribers: list[FrameSync] = []
        self.pixel_unit = self._unit_from_cci()
        self.frames = LeptonFrameSource(
            vospi,
            clock_hz=spi_clock_hz,
            telemetry_location=TELEMETRY_LOCATIONS[telemetry_location],
            source=byte_source,
            on_frame=self._on_frame,
            replay_fps=replay_fps,
        )
        self.capture_timeout_s = capture_timeout_s
        try:
            self.frames.open(probe_timeout_s=probe_timeout_s)
        except BaseException:
            self._close_bus()
            raise

    def _unit_from_cci(self) -> str | None:
        """The pixel unit the CCI says (None without a CCI, or if it does not answer)."""
        if self._bus is None:
            return None
        driver = Lepton35.probe(self._bus, bus_name="lepton CCI")
        if driver is None:
            return None
        try:
            if not (driver.radiometry() and driver.tlinear()):
                return "counts"
            return UNITS_K[driver.tlinear_resolution_k()]
        except I2CError as e:
            log.warning("the Lepton's radiometry settings not read: %s", e)
            return None

    # -- the Board protocol ----------------------------------------------------------------

    def buses(self) -> Mapping[int, I2CBus]:
        return {} if self._bus is None else {self.port: self._bus}

    def sensors(self) -> Mapping[int, SensorDriver]:
        """Ports whose driver is not found on a bus: the Lepton without its CCI."""
        return {} if self._bus is not None else {self.port: LeptonWithoutCCI()}

    def on_frame_sync(self, callback: FrameSync) -> None:
        """Call ``callback(port, frame, timestamp_ns)`` as each whole frame arrives."""
        self._subscribers.append(callback)

    def _on_frame(self, frame: VoSPIFrame) -> None:
        for callback in self._subscribers:
            callback(self.port, frame.number, frame.timestamp_ns)

    def program(self, port: int, function: str, state: Mapping[str, int]) -> None:
        """Nothing beyond the sensor: the Lepton runs free."""

    def capture(self, port: int, *, frame: int | None = None, timeout_s: float = 10.0) -> Frame:
        """The next whole frame, or frame ``frame`` (recent, or soon to come)."""
        if port != self.port:
            raise PortError(f"port {port} does not exist; ports: [{self.port}]")
        timeout_s = min(timeout_s, self.capture_timeout_s)
        if frame is None:
            return self._frame(self.frames.read_frame(timeout_s=timeout_s))
        got = self.frames.recent(frame)
        if got is None:
            got = self.frames.read_frame(after=frame - 1, timeout_s=timeout_s)
            if got.number != frame:
                raise FrameNotAvailableError(
                    f"port {port}: frame {frame} is not kept (the Lepton's frames are "
                    f"counted by its own counter; the next one is {got.number})"
                )
        return self._frame(got)

    def _frame(self, got: VoSPIFrame) -> Frame:
        extra: dict[str, Any] = {"pixel_unit": self.pixel_unit}
        if got.telemetry is not None:
            t = got.telemetry
            extra["pixel_unit"] = UNITS_K[t.tlinear_resolution_k] if t.tlinear else "counts"
            extra["telemetry"] = t.to_metadata()
        return Frame(
            image=got.image, frame=got.number, timestamp_ns=got.timestamp_ns, metadata=extra
        )

    def port_status(self, port: int) -> dict[str, Any]:
        """The VoSPI stream's state (`LeptonFrameSource.health`)."""
        return self.frames.health()

    def close(self) -> None:
        self.frames.close()
        self._close_bus()

    def _close_bus(self) -> None:
        close = getattr(self._bus, "close", None)
        if close is not None:
            close()
