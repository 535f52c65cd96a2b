"""Exception tree of the camera daemon.

Each error has a domain base (`CameraError`) and the built-in it behaves like, so callers
can catch either.
"""

from __future__ import annotations


class CameraError(Exception):
    """Base of every error raised by elphel_camd."""


class ConfigError(CameraError, ValueError):
    """The configuration file or environment is unreadable or names unknown settings."""


class I2CError(CameraError, OSError):
    """An I2C transfer failed: names the bus, the device address and the register."""

    def __init__(self, message: str, *, bus: str, address: int, register: int | None) -> None:
        super().__init__(message)
        self.bus = bus
        self.address = address
        self.register = register


class PortI2CError(I2CError):
    """An I2C failure while a port's change was written; the change was taken back.

    Names the port, the bus, the device address and the register, and keeps the
    original error as ``__cause__``.
    """

    def __init__(self, port: int, cause: I2CError) -> None:
        register = "?" if cause.register is None else f"0x{cause.register:02x}"
        super().__init__(
            f"port {port}: I2C failure at device 0x{cause.address:02x} register {register} "
            f"on {cause.bus}; nothing was changed ({cause})",
            bus=cause.bus,
            address=cause.address,
            register=cause.register,
        )
        self.port = port


class SensorNotFoundError(CameraError, LookupError):
    """No sensor answered on a port, or it answered with an unknown chip id."""


class ParameterRangeError(CameraError, ValueError):
    """A parameter value is outside what the sensor or the board allows."""

    def __init__(self, name: str, value: object, allowed: str) -> None:
        super().__init__(f"{name}={value!r} is out of range; allowed: {allowed}")
        self.name = name
        self.value = value
        self.allowed = allowed


class RegisterNotFoundError(ParameterRangeError, LookupError):
    """A register address the port's sensor does not have (names the ones it has)."""


class StateWriteError(CameraError, OSError):
    """The state directory cannot be written (disk full, read-only): the change was refused.

    Names the file and the operating system's reason; the settings in effect and on disk
    are the last ones saved.
    """


class FrameScheduleError(CameraError, ValueError):
    """A change was requested for a frame that cannot take it."""

    def __init__(self, message: str, *, frame: int, this_frame: int, earliest: int, latest: int):
        super().__init__(message)
        self.frame = frame
        self.this_frame = this_frame
        self.earliest = earliest
        self.latest = latest


class FrameTooLateError(FrameScheduleError):
    """The target frame is too close: its registers had to be written already (Elphel TOOLATE)."""


class FrameTooEarlyError(FrameScheduleError):
    """The target frame is more than 14 frames ahead (Elphel TOOEARLY)."""


class FrameNotAvailableError(CameraError, LookupError):
    """A frame that is no longer (or not yet) in the ring buffer."""


class PortError(CameraError, LookupError):
    """A sensor port number that the board does not have."""


class CaptureUnavailableError(CameraError, RuntimeError):
    """The board has no image path for this port (e.g. a bare I2C board)."""


class UnsupportedError(CameraError, ValueError):
    """The sensor or board cannot do what was asked (e.g. a window on the Lepton)."""


class LeptonError(I2CError):
    """The Lepton refused a CCI command: names the command, its id and the error code.

    ``code`` is the signed 8-bit error of the status register (negative), or None when the
    camera did not answer in time.
    """

    def __init__(
        self,
        message: str,
        *,
        bus: str,
        address: int,
        register: int | None,
        command: int,
        code: int | None,
    ) -> None:
        super().__init__(message, bus=bus, address=address, register=register)
        self.command = command
        self.code = code


class VideoNodeError(CameraError, OSError):
    """A V4L2 node that cannot serve frames: missing, not a capture node, no raw format.

    The message names the node and what it offers or what is missing.
    """


class DeviceBusyError(VideoNodeError):
    """Another program holds the node's buffers (EBUSY): it is streaming already."""


class PortDisconnectedError(CameraError, ConnectionError):
    """The port's node went away mid-stream; the port reconnects when it returns."""


class ControlRefusedError(ParameterRangeError):
    """A value the driver refuses for one of its controls: names the driver's limits."""
