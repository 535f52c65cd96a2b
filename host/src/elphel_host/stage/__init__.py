"""Stage client: the ESP8266 linear stage over any pyserial URL.

`StageClient` speaks the line protocol (docs/stage-protocol.md); `Positioner` adds
millimetres, calibration, backlash measurement and caliper closed-loop moves.
"""

from elphel_host.stage.client import Identity, MoveStatus, StageClient
from elphel_host.stage.model import StageModel
from elphel_host.stage.positioning import Calibration, MoveResult, Positioner
from elphel_host.stage.protocol import StageStatus

__all__ = [
    "Calibration",
    "Identity",
    "MoveResult",
    "MoveStatus",
    "Positioner",
    "StageClient",
    "StageModel",
    "StageStatus",
]
