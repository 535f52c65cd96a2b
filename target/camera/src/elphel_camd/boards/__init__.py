"""Camera boards: the `Board` protocol, `Frame`, the I2C, Lepton and mixed boards, the registry.

Boards are found by name (`board_factories`): ``i2c``, ``v4l2``, ``lepton`` and ``mixed``
are built in; other packages add theirs through the ``elphel_camd.boards`` entry-point
group.
"""

from elphel_camd.boards.base import Board, Frame, FrameSync
from elphel_camd.boards.i2c import I2CBoard
from elphel_camd.boards.lepton import LeptonBoard
from elphel_camd.boards.mixed import MixedBoard
from elphel_camd.boards.registry import ENTRY_POINT_GROUP, BoardFactory, board_factories

__all__ = [
    "ENTRY_POINT_GROUP",
    "Board",
    "BoardFactory",
    "Frame",
    "FrameSync",
    "I2CBoard",
    "LeptonBoard",
    "MixedBoard",
    "board_factories",
]
