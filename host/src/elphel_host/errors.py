"""Exception tree of the host library: a domain base plus the built-in each error behaves like."""

from __future__ import annotations


class ElphelError(Exception):
    """Base of every error the host library raises on purpose."""


class CameraClientError(ElphelError, RuntimeError):
    """The camera daemon refused a request or could not be reached."""


class CameraAuthError(CameraClientError, PermissionError):
    """The daemon answered 401/403: missing or wrong token."""


class UnsupportedError(CameraClientError, NotImplementedError):
    """The camera's backend cannot do what was asked; the message names the feature and why."""


class CameraParameterError(CameraClientError, ValueError):
    """A parameter value the camera's parameter model refuses; nothing was written.

    ``parameter``, ``value`` and ``allowed`` say which and why, as elphel-camd's 422 does.
    """

    def __init__(self, message: str, *, parameter: str, value: object, allowed: str) -> None:
        super().__init__(message)
        self.parameter = parameter
        self.value = value
        self.allowed = allowed


class ReadBackError(CameraClientError):
    """After a change was in effect the camera reported another value than the one asked."""

    def __init__(self, message: str, *, parameter: str, asked: int, found: int | None) -> None:
        super().__init__(message)
        self.parameter = parameter
        self.asked = asked
        self.found = found


class QuadCaptureError(CameraClientError):
    """A quad set could not be taken: too few sensor ports, or frames not of one trigger."""


class QuadCaptureTimeout(QuadCaptureError, TimeoutError):  # noqa: N818 - like StageTimeout
    """The camera's frames did not reach the frame a quad capture waits for."""


class EventStreamError(CameraClientError, ValueError):
    """An event of the daemon's event stream is malformed: names the event and the field."""


class DeviceError(ElphelError):
    """A device (camera, stage) broke a bound of `elphel_host.limits` or its own protocol."""


class DeviceLimitError(DeviceError, ValueError):
    """An answer or file claims or sends more than a bound allows; names device and bound."""


class DeviceTimeout(DeviceError, TimeoutError):  # noqa: N818 - like StageTimeout
    """A request had no complete answer within its overall deadline."""


class DeviceAnswerError(DeviceError, ValueError):
    """An answer lacks the documented form: names the device, the field and what is allowed."""


class InputFormatError(ElphelError, ValueError):
    """A file or directory given as input does not have the documented format."""


class Jp4FormatError(InputFormatError):
    """A JP4/JP46/JPEG frame is damaged or lacks what decoding needs (Exif, MakerNote, size)."""


class ScaleError(ElphelError, ValueError):
    """An up-sampling factor outside what the operation allows."""

    def __init__(self, value: object, allowed: str) -> None:
        super().__init__(f"scale={value!r}; allowed: {allowed}")
        self.value = value
        self.allowed = allowed


class CaptureTimeout(ElphelError, TimeoutError):  # noqa: N818 - like StageTimeout
    """A burst capture did not finish within the time a caller waited for it."""


class FusionError(ElphelError, RuntimeError):
    """Fusing a burst failed (a frame could not be loaded, the reconstruction raised, ...)."""


class StageError(ElphelError):
    """The linear stage failed or refused an operation."""


class StageConnectionError(StageError, ConnectionError):
    """The link to the stage board could not be opened or was lost."""


class StageTimeout(StageError, TimeoutError):  # noqa: N818 - the name users expect
    """The stage did not answer or finish within the deadline."""


class StageProtocolError(StageError):
    """A reply was garbled, truncated or not what the protocol allows."""


class StageCommandError(StageError):
    """The board answered a command with an error code (see docs/stage-protocol.md)."""

    def __init__(self, message: str, *, code: int = 0, keyword: str = "") -> None:
        super().__init__(message)
        self.code = code
        self.keyword = keyword


class StageLimitError(StageCommandError, ValueError):
    """A target lies outside the stage's soft limits."""


class StageBusyError(StageCommandError):
    """The stage is moving or homing; stop it first."""


class StageNotHomedError(StageCommandError):
    """The stage does not know its position: home it (or re-sync from the caliper)."""


class StageAlarmError(StageCommandError):
    """A limit switch closed or homing failed; HOME clears it."""


class StageCaliperError(StageCommandError):
    """The caliper gave no frame, a frame that failed to decode, or unstable readings."""


class StageResetError(StageError):
    """The board reset (a new boot id): its step position is no longer known."""


class StageStallError(StageError):
    """The caliper did not confirm a commanded move: motor stalled or steps were lost."""


class StageClosedLoopError(StageError):
    """A closed-loop move could not reach the tolerance within its attempts."""
