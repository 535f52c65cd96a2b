"""One port of the simulated board seen as a board of its own (one daemon per camera).

A rig of several single-camera boards (two Raspberry Pis, each with its own camera and
its own elphel-camd) is simulated by one `SimCameraBoard`, so that the cameras share one
world, one stage and one clock; each daemon is given a `PortView` of its camera's port,
which it sees as its port 0.
"""

from __future__ import annotations

from collections.abc import Mapping

from elphel_camd.boards import Frame
from elphel_camd.errors import PortError
from elphel_camd.i2c.bus import I2CBus
from elphel_sim.board import FrameSync, SimCameraBoard


class PortView:
    """Port ``port`` of a simulated board as port 0 of a one-port board.

    Parameters
    ----------
    board
        The shared board; its owner closes it (closing a view releases nothing).
    port
        The board's port this view shows.
    """

    def __init__(self, board: SimCameraBoard, port: int) -> None:
        if port not in board.fpga:
            raise PortError(f"port {port} has no simulated sensor; ports: {sorted(board.fpga)}")
        self.board = board
        self.port = port
        self.name = board.name
        # One camera alone: no common trigger shared with other ports.
        self.capabilities = board.capabilities - {"trigger"}

    def _check(self, port: int) -> None:
        if port != 0:
            raise PortError(f"port {port} does not exist; ports: [0]")

    def buses(self) -> Mapping[int, I2CBus]:
        return {0: self.board.bus(self.port)}

    def on_frame_sync(self, callback: FrameSync) -> None:
        """Call ``callback(0, frame, timestamp_ns)`` at every frame start of this port."""

        def forward(port: int, frame: int, timestamp_ns: int) -> None:
            if port == self.port:
                callback(0, frame, timestamp_ns)

        self.board.on_frame_sync(forward)

    def program(self, port: int, function: str, state: Mapping[str, int]) -> None:
        self._check(port)
        self.board.program(self.port, function, state)

    def capture(self, port: int, *, frame: int | None = None, timeout_s: float = 10.0) -> Frame:
        self._check(port)
        return self.board.capture(self.port, frame=frame, timeout_s=timeout_s)

    def pin_frames(self, port: int, count: int, *, frame: int | None = None) -> int:
        """As `SimCameraBoard.pin_frames`, on this view's port."""
        self._check(port)
        return self.board.pin_frames(self.port, count, frame=frame)

    def release_frames(self, port: int, frames: range | list[int]) -> None:
        self._check(port)
        self.board.release_frames(self.port, frames)

    def close(self) -> None:
        """Nothing to release: the shared board belongs to whoever built the views."""
