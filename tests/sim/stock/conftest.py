"""A simulated stock NC393 in process: the mixed scenario's board, its clock running."""

import pytest
from fastapi.testclient import TestClient

from elphel_sim.board import SimCameraBoard
from elphel_sim.scenarios import build
from elphel_sim.stock.firmware import StockFirmware
from elphel_sim.stock.server import imgsrv_app, parsedit_app

# A small window at 40 fps: quick to render, and the ring's 64 frames last 1.6 s.
SMALL = {"WOI_WIDTH": 256, "WOI_HEIGHT": 128, "EXPOS": 5000, "FP1000SLIM": 40000, "FPSFLAGS": 1}


@pytest.fixture
def firmware():
    """Ports 0 MT9P006 (a small window), 1 MT9F002, 2 Lepton 3.5, 3 empty; no noise."""
    board = SimCameraBoard(build("mixed", seed=3), seed=3, noise=False)
    fw = StockFirmware(board)
    fw.service.set_params(0, SMALL)
    board.start_clock()
    assert fw.wait_frame(0, fw.frame(0) + 5)
    fw.service.capture(0)  # the first image builds the scene's texture (longer than the ring)
    yield fw
    fw.close()


@pytest.fixture
def web(firmware):
    with TestClient(parsedit_app(firmware)) as client:
        yield client


@pytest.fixture
def imgsrv(firmware):
    """The four ports' image servers; a frame's pixels follow its head at once."""
    clients = [TestClient(imgsrv_app(firmware, port, pixels_after_s=0)) for port in range(4)]
    yield clients
    for c in clients:
        c.close()
