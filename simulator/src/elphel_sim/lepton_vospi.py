"""A scenario's Lepton ports as a Lepton's VoSPI byte stream, read by elphel-camd's lepton board.

For each Lepton 3.5 port of a `SimCameraBoard`, `vospi_board` builds a `SimVoSPIStream`
whose unique frames are that port's frames as the board forms them (with the telemetry
rows when the CCI turned them on), behind a `SimSpidev` that keeps real-time pace, and
elphel-camd's `LeptonBoard` on top. The bytes go through the same spidev source, VoSPI
reader and frame source as a real Lepton's. The CCI stays with the board's own daemon
(the camera's port), so the VoSPI board is the Lepton without its CCI.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from elphel_camd.boards.lepton import LeptonBoard
from elphel_camd.errors import CameraError
from elphel_camd.vospi import SpidevSource
from elphel_camd.vospi import telemetry as tm
from elphel_camd.vospi.packets import WIDTH
from elphel_camd.vospi.sources import BUFSIZ_DEFAULT
from elphel_sim.board import SimCameraBoard
from elphel_sim.vospi import SimSpidev, SimVoSPIStream

LEPTON_MODEL = "LEPTON35"
UNIFORM_CENTI_K = 29315  # 20 °C: what the stream shows before the port's first frame
FORMING_WAIT_S = 10.0  # how long a capture waits for a frame the board has yet to form


def lepton_ports(board: SimCameraBoard) -> list[int]:
    """The board's Lepton ports, in order."""
    return [port for port, spec in board.ports.items() if spec.model == LEPTON_MODEL]


class PortFrames:
    """The rows of the VoSPI stream's next unique frame: the port's next frame.

    Parameters
    ----------
    board
        The simulated board forming the port's frames.
    port
        The Lepton's port.
    timeout_s
        How long to wait for the port's next frame; when none comes (the board is
        closing), the last frame is sent again (before the first: a uniform 20 °C).
    """

    def __init__(
        self, board: SimCameraBoard, port: int, *, timeout_s: float = FORMING_WAIT_S
    ) -> None:
        self.board = board
        self.port = port
        self.timeout_s = timeout_s
        self._last: NDArray[np.uint16] = np.full((tm.HEIGHT, WIDTH), UNIFORM_CENTI_K, np.uint16)

    def __call__(self, number: int) -> NDArray[np.uint16]:
        try:
            frame = self.board.capture(self.port, timeout_s=self.timeout_s)
        except (TimeoutError, CameraError):
            return self._last
        self._last = np.asarray(frame.image, dtype=np.uint16)
        return self._last


@dataclass(frozen=True)
class VoSPIPort:
    """A Lepton port served through VoSPI: elphel-camd's board and the simulated stream.

    The stream's ``sim_*`` hooks inject VoSPI faults (CRC errors, lost bytes, stalls,
    lost sync) into what the board reads.
    """

    port: int
    board: LeptonBoard
    stream: SimVoSPIStream


def vospi_board(board: SimCameraBoard, port: int, *, seed: int = 0) -> VoSPIPort:
    """elphel-camd's lepton board reading port ``port``'s simulated VoSPI stream.

    ``seed`` seeds the stream's fault draws (`SimVoSPIStream`).
    """
    stream = SimVoSPIStream(PortFrames(board, port), seed=seed)
    spidev = SimSpidev(stream, path=f"simulated spidev of port {port}", time_scale=1.0)
    source = SpidevSource(spidev, bufsiz=BUFSIZ_DEFAULT)
    # No probe, and captures wait longer than for a real Lepton: the packets wait for the
    # port's frames to be formed, which a loaded machine can take seconds to do.
    lepton = LeptonBoard(
        spidev.path, byte_source=source, probe_timeout_s=0, capture_timeout_s=FORMING_WAIT_S
    )
    return VoSPIPort(port, lepton, stream)
