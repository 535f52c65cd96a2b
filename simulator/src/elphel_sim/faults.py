"""Faults injected into a running simulated rig over its inspection endpoint (``sim_url``).

``elphel-sim up`` serves these next to the truth (``{sim_url}/stage``...), so a test of a
user's own script can make the rig fail the way hardware does and check what the script
does about it:

* ``i2c_nak`` — the next ``count`` I2C transfers on a sensor port's bus are not
  acknowledged (the chip's hooks: `SimI2CBus.sim_nak`). elphel-camd tries each transfer
  twice, so ``count`` 1 is absorbed by its retry and ``count`` 2 fails one access: a
  register access is answered 503 (``"error": "i2c"``, naming the port, the chip's address
  and the register); a parameter change written at a frame sync fails there and is
  published as an ``error`` event.
* ``motor_stall`` — the stage motor no longer moves on its step pulses
  (`SimStage.sim_stall`): a move ends where it started and the caliper says so.
* ``stage_link_drop`` — the stage's TCP link is down (`SimStage.sim_link_down`): the
  open connection is cut and every new one is cut as soon as it is made, until cleared.

``POST /faults`` injects one (a JSON object with ``kind`` and its options),
``GET /faults`` lists those in effect, ``DELETE /faults`` clears them all.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException
from pydantic import BaseModel, ConfigDict, Field

from elphel_sim.board import SimCameraBoard
from elphel_sim.stage_server import SimStage

FAULT_KINDS = ("i2c_nak", "motor_stall", "stage_link_drop")


class I2CNak(BaseModel):
    """NAK the next ``count`` transfers on the bus of sensor port ``port``."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    kind: Literal["i2c_nak"]
    port: int = Field(0, ge=0)
    count: int = Field(2, ge=1, description="transfers not acknowledged; elphel-camd tries twice")


class MotorStall(BaseModel):
    """Stall the stage motor: step pulses no longer move the carriage."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    kind: Literal["motor_stall"]


class StageLinkDrop(BaseModel):
    """Take the stage's TCP link down until the faults are cleared."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    kind: Literal["stage_link_drop"]


Fault = Annotated[I2CNak | MotorStall | StageLinkDrop, Field(discriminator="kind")]


def faults_in_effect(board: SimCameraBoard, stage: SimStage | None) -> list[dict[str, Any]]:
    """The faults the rig has now, in the form ``POST /faults`` takes (``count`` left)."""
    out: list[dict[str, Any]] = []
    for port in sorted(board.ports):
        left, _address = board.bus(port).sim_naks_pending
        if left:
            out.append({"kind": "i2c_nak", "port": port, "count": left})
    if stage is not None and stage.mech.stalled:
        out.append({"kind": "motor_stall"})
    if stage is not None and stage.link_down:
        out.append({"kind": "stage_link_drop"})
    return out


def fault_router(board: SimCameraBoard, stage: SimStage | None) -> APIRouter:
    """``GET``, ``POST`` and ``DELETE /faults`` on this board and stage."""
    router = APIRouter()

    def need_stage(kind: str) -> SimStage:
        if stage is None:
            raise HTTPException(status_code=404, detail=f"{kind}: this rig has no simulated stage")
        return stage

    @router.get("/faults")
    def list_faults() -> dict[str, Any]:
        """The faults in effect."""
        return {"faults": faults_in_effect(board, stage)}

    @router.post("/faults")
    def inject(fault: Fault) -> dict[str, Any]:
        """Inject one fault; answers the faults in effect."""
        if isinstance(fault, I2CNak):
            if fault.port not in board.ports:
                raise HTTPException(
                    status_code=422,
                    detail=f"port={fault.port}; allowed: one of {sorted(board.ports)}",
                )
            board.bus(fault.port).sim_nak(fault.count)
        elif isinstance(fault, MotorStall):
            need_stage(fault.kind).sim_stall(True)
        else:
            need_stage(fault.kind).sim_link_down(True)
        return {"faults": faults_in_effect(board, stage)}

    @router.delete("/faults")
    def clear() -> dict[str, Any]:
        """Clear every fault: the buses answer, the motor moves, the link comes back."""
        for port in board.ports:
            board.bus(port).sim_nak(0)
        if stage is not None:
            stage.sim_stall(False)
            stage.sim_link_down(False)
        return {"faults": faults_in_effect(board, stage)}

    return router
