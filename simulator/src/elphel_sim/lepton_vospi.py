"""A scenario's Lepton ports as a Lepton's VoSPI byte stream, read by elphel-camd's lepton board.

For each Lepton 3.5 port of a `SimCameraBoard`, `vospi_board` builds a `SimVoSPIStream`
whose unique frames are that port's frames as the board forms them (with the telemetry
rows when the CCI turned them on), behind a `SimSpidev` that keeps real-time pace, and
elphel-camd's `LeptonBoard` on top. The bytes go through the same spidev source, VoSPI
reader and frame source as a real Lepton's. The CCI stays with the board's own daemon
(the camera's port), so the VoSPI board is the Lepton without its CCI.

`vospi_fault_router` serves the streams' fault hooks on the inspection endpoint:
``POST {sim_url}/lepton/{port}/faults`` with ``{"kind": "stall", "duration_s": 2}`` (or
``lose_sync``, ``lose_bytes`` with ``count``, ``crc_errors`` with ``rate``), and ``GET``
for the faults so far.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from fastapi import APIRouter, HTTPException
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

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


class VoSPIFault(BaseModel):
    """A fault of a Lepton port's VoSPI stream, from now on (`SimVoSPIStream`'s hooks)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    kind: Literal["crc_errors", "lose_bytes", "stall", "lose_sync"]
    rate: float = Field(1e-3, ge=0, le=1, description="crc_errors: per video packet")
    count: int = Field(1000, ge=1, le=1_000_000, description="lose_bytes: bytes lost")
    duration_s: float = Field(1.0, gt=0, le=60, description="stall: seconds without segments")


def inject(stream: SimVoSPIStream, fault: VoSPIFault) -> None:
    """Start ``fault`` on ``stream`` at the stream's present time."""
    if fault.kind == "crc_errors":
        stream.sim_crc_errors(fault.rate)
    elif fault.kind == "lose_bytes":
        stream.sim_lose_bytes(stream.t, fault.count)
    elif fault.kind == "stall":
        stream.sim_stall(stream.t, fault.duration_s)
    else:
        stream.sim_lose_sync(stream.t)


def fault_record(stream: SimVoSPIStream) -> dict[str, Any]:
    """The stream's faults so far (virtual seconds; ``end_s`` null while one lasts)."""
    return {
        "t_s": stream.t,
        "crc_error_rate": stream.crc_rate,
        "faults": [
            {
                "kind": f.kind,
                "start_s": f.start_s,
                "end_s": None if math.isnan(f.end_s) else f.end_s,
            }
            for f in stream.faults
            if f.kind != "crc"
        ],
        "crc_errors": sum(f.kind == "crc" for f in stream.faults),
    }


def vospi_fault_router(ports: Sequence[VoSPIPort]) -> APIRouter:
    """``GET`` and ``POST /lepton/{port}/faults``: the VoSPI faults of each Lepton port."""
    router = APIRouter()
    streams = {p.port: p.stream for p in ports}

    def stream_of(port: int) -> SimVoSPIStream:
        if port not in streams:
            raise HTTPException(
                status_code=404,
                detail=f"port {port} has no VoSPI stream; Lepton ports: {sorted(streams)}",
            )
        return streams[port]

    @router.get("/lepton/{port}/faults")
    def faults(port: int) -> dict[str, Any]:
        """The VoSPI faults injected so far, and the stream's time."""
        return fault_record(stream_of(port))

    @router.post("/lepton/{port}/faults")
    def add(port: int, fault: VoSPIFault) -> dict[str, Any]:
        """Inject one VoSPI fault now; answers the faults so far.

        The fault is listed once the stream reaches it, at the reader's next transfer.
        """
        stream = stream_of(port)
        inject(stream, fault)
        return fault_record(stream)

    return router
