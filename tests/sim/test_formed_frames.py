"""A frame whose image was asked for stays available for a while, out of the ring too.

A client that gave up on a capture while its image formed (a busy machine) and asks for
the same frame again gets it, formed once (elphel_sim.board.FORMED_KEEP_S).
"""

import pytest

from elphel_camd.errors import FrameNotAvailableError
from elphel_sim import board as board_module
from elphel_sim.board import SimCameraBoard
from elphel_sim.scenarios import build

SMALL = {"WOI_WIDTH": 64, "WOI_HEIGHT": 48, "WOI_LEFT": 1200, "WOI_TOP": 900}


@pytest.fixture
def board():
    sim = SimCameraBoard(build("default", seed=5), seed=5, noise=False)
    sim.sim_advance(frames=2)
    yield sim
    sim.close()


def test_a_frame_asked_for_is_served_again_after_it_left_the_ring(board):
    first = board.capture(0)
    board.sim_advance(frames=100)  # the ring holds 64
    assert all(r.frame != first.frame for r in board.fpga[0].ring)
    again = board.capture(0, frame=first.frame)
    assert again.frame == first.frame and again.image is first.image  # formed once
    other = board.fpga[0].ring[0].frame - 1  # never asked for, out of the ring
    with pytest.raises(FrameNotAvailableError, match="no longer in the ring"):
        board.capture(0, frame=other)


def test_frames_asked_for_are_let_go_after_formed_keep_s(board, monkeypatch):
    first = board.capture(0)
    monkeypatch.setattr(board_module, "FORMED_KEEP_S", 0.0)
    board.sim_advance(frames=100)
    with pytest.raises(FrameNotAvailableError, match="no longer in the ring"):
        board.capture(0, frame=first.frame)
