"""Errors of the V4L2 image path: a missing or unusable node, a busy device, a lost one."""

from __future__ import annotations

from elphel_camd.errors import CameraError, ParameterRangeError


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
