"""Boards and the camera service on top of them.

A board supplies, per sensor port, an I2C bus and (where it has an image path) frames.
`Camera` detects the sensor on every port and answers what the REST API asks. Boards are
found by name: ``i2c`` is built in (sensors on Linux /dev/i2c-N buses, no image path);
other packages add boards through the ``elphel_camd.boards`` entry-point group (the
simulator registers ``sim``), so the daemon never imports them.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from elphel_camd import __version__
from elphel_camd.errors import CaptureUnavailableError, PortError, SensorNotFoundError
from elphel_camd.i2c.bus import I2CBus, open_bus
from elphel_camd.sensors import SensorDriver, detect


@dataclass(frozen=True)
class Frame:
    """One image from a port with its frame number and capture time."""

    image: NDArray[np.uint16]
    frame: int
    timestamp_ns: int


class Board(Protocol):
    """What the daemon needs from a camera board."""

    name: str

    def buses(self) -> Mapping[int, I2CBus]:
        """Sensor port number -> the I2C bus of that port."""
        ...

    def capture(self, port: int) -> Frame:
        """The next frame of a port (raises CaptureUnavailableError without an image path)."""
        ...

    def close(self) -> None:
        """Release buses and threads."""
        ...


class I2CBoard:
    """Sensors on Linux I2C buses, one bus per port; images come from elsewhere.

    Parameters
    ----------
    bus_urls
        One bus URL per port, e.g. ``["/dev/i2c-0", "/dev/i2c-1"]``.
    """

    name = "i2c"

    def __init__(self, bus_urls: list[str]) -> None:
        if not bus_urls:
            raise ValueError("the i2c board needs at least one bus (e.g. --bus /dev/i2c-0)")
        self._buses = {port: open_bus(url) for port, url in enumerate(bus_urls)}

    def buses(self) -> Mapping[int, I2CBus]:
        return self._buses

    def capture(self, port: int) -> Frame:
        raise CaptureUnavailableError(
            f"port {port}: the i2c board controls sensors only; "
            "it has no image path to capture from"
        )

    def close(self) -> None:
        for bus in self._buses.values():
            close = getattr(bus, "close", None)
            if close is not None:
                close()


BoardFactory = Callable[..., Board]


def board_factories() -> dict[str, BoardFactory]:
    """Boards by name: the built-in ones and those registered by other packages."""
    found: dict[str, BoardFactory] = {"i2c": I2CBoard}
    for ep in entry_points(group="elphel_camd.boards"):
        found.setdefault(ep.name, ep.load())
    return found


class Camera:
    """The daemon's view of a board: detected sensors per port and capture with metadata."""

    def __init__(self, board: Board) -> None:
        self.board = board
        self.sensors: dict[int, SensorDriver | None] = {
            port: detect(bus, bus_name=f"port {port}") for port, bus in board.buses().items()
        }
        self._locks = {port: threading.Lock() for port in self.sensors}
        self.started_ns = time.time_ns()

    def sensor(self, port: int) -> SensorDriver:
        """The driver on a port.

        Raises PortError for a port the board lacks, SensorNotFoundError for an empty one.
        """
        if port not in self.sensors:
            raise PortError(f"port {port} does not exist; ports: {sorted(self.sensors)}")
        driver = self.sensors[port]
        if driver is None:
            raise SensorNotFoundError(f"port {port}: no sensor detected")
        return driver

    def info(self) -> dict[str, Any]:
        ports = []
        for port, driver in sorted(self.sensors.items()):
            entry: dict[str, Any] = {"port": port, "sensor": None}
            if driver is not None:
                entry["sensor"] = driver.identity()
            ports.append(entry)
        return {
            "board": self.board.name,
            "daemon": "elphel-camd",
            "version": __version__,
            "ports": ports,
        }

    def capture(self, port: int) -> tuple[Frame, dict[str, Any]]:
        """The next frame of a port and its metadata (the parameters it was taken with)."""
        driver = self.sensor(port)
        with self._locks[port]:
            params = driver.read_params()
            frame = self.board.capture(port)
        metadata: dict[str, Any] = {
            "frame": frame.frame,
            "timestamp_ns": frame.timestamp_ns,
            "port": port,
            "sensor": driver.model,
            "bayer": _bayer_after_flips(
                driver.bayer, params.get("FLIPH", 0), params.get("FLIPV", 0)
            ),
            **params,
        }
        return frame, metadata

    def close(self) -> None:
        self.board.close()


def _bayer_after_flips(bayer: str | None, fliph: int, flipv: int) -> str | None:
    """Bayer pattern of the first pixel once the readout is mirrored."""
    if bayer is None:
        return None
    cell = [bayer[0:2], bayer[2:4]]
    if flipv:
        cell = cell[::-1]
    if fliph:
        cell = [row[::-1] for row in cell]
    return cell[0] + cell[1]
