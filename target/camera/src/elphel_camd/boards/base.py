"""What the daemon needs from a camera board: the `Board` protocol and the `Frame` it hands out.

A board supplies, per sensor port, an I2C bus and, where it has them, frame syncs, an FPGA
(trigger generator, photo-finish) and an image path. The camera service
(`elphel_camd.service.CameraService`) is built on top of one.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from elphel_camd.i2c.bus import I2CBus

FrameSync = Callable[[int, int, int], None]


@dataclass(frozen=True)
class Frame:
    """One image from a port with its frame number and capture time."""

    image: NDArray[np.uint16]
    frame: int
    timestamp_ns: int
    strip_period_ns: int = 0  # photo-finish: time from one strip to the next (0 otherwise)
    metadata: Mapping[str, Any] = field(default_factory=dict)  # what the board adds (telemetry)


class Board(Protocol):
    """What the daemon needs from a camera board.

    ``capabilities`` may hold ``"frames"`` (frame syncs: changes can be scheduled on
    frames), ``"capture"`` (an image path), ``"trigger"`` (a common trigger generator) and
    ``"photofinish"``. A board may also have ``sensors()`` (port -> driver, for ports whose
    sensor is not found on an I2C bus) and ``port_status(port)`` (its frame stream's
    state, a dict with at least ``state``: ``streaming`` when frames come).
    """

    name: str
    capabilities: frozenset[str]

    def buses(self) -> Mapping[int, I2CBus]:
        """Sensor port number -> the I2C bus of that port."""
        ...

    def on_frame_sync(self, callback: FrameSync) -> None:
        """Call ``callback(port, frame, timestamp_ns)`` at every frame start."""
        ...

    def program(self, port: int, function: str, state: Mapping[str, int]) -> None:
        """Program the board's own part of a function (trigger, photo-finish) for a state."""
        ...

    def capture(self, port: int, *, frame: int | None = None, timeout_s: float = 10.0) -> Frame:
        """The next frame of a port, or a recent one by number."""
        ...

    def close(self) -> None:
        """Release buses and threads."""
        ...
