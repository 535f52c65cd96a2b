"""Boards by name: the built-in ``i2c``, ``v4l2``, ``lepton`` and ``mixed``, and the entry points.

Other packages add boards through that entry-point group (the simulator registers
``sim``), so the daemon never imports them. ``elphel-camd --board NAME`` picks one.
"""

from __future__ import annotations

from collections.abc import Callable
from importlib.metadata import entry_points

from elphel_camd.boards.base import Board
from elphel_camd.boards.i2c import I2CBoard
from elphel_camd.boards.lepton import LeptonBoard
from elphel_camd.boards.mixed import MixedBoard
from elphel_camd.boards.v4l2 import V4L2Board

ENTRY_POINT_GROUP = "elphel_camd.boards"

BoardFactory = Callable[..., Board]


def board_factories() -> dict[str, BoardFactory]:
    """Boards by name: the built-in ones and those registered by other packages."""
    found: dict[str, BoardFactory] = {
        "i2c": I2CBoard,
        "v4l2": V4L2Board,
        "lepton": LeptonBoard,
        "mixed": MixedBoard,
    }
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        found.setdefault(ep.name, ep.load())
    return found
