"""Exception tree of the camera daemon.

Each error has a domain base (`CameraError`) and the built-in it behaves like, so callers
can catch either.
"""

from __future__ import annotations


class CameraError(Exception):
    """Base of every error raised by elphel_camd."""


class I2CError(CameraError, OSError):
    """An I2C transfer failed: names the bus, the device address and the register."""

    def __init__(self, message: str, *, bus: str, address: int, register: int | None) -> None:
        super().__init__(message)
        self.bus = bus
        self.address = address
        self.register = register


class SensorNotFoundError(CameraError, LookupError):
    """No sensor answered on a port, or it answered with an unknown chip id."""


class ParameterRangeError(CameraError, ValueError):
    """A parameter value is outside what the sensor or the board allows."""

    def __init__(self, name: str, value: object, allowed: str) -> None:
        super().__init__(f"{name}={value!r} is out of range; allowed: {allowed}")
        self.name = name
        self.value = value
        self.allowed = allowed


class PortError(CameraError, LookupError):
    """A sensor port number that the board does not have."""


class CaptureUnavailableError(CameraError, RuntimeError):
    """The board has no image path for this port (e.g. a bare I2C board)."""
