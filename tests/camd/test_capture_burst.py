"""Multi-frame capture: every frame requested or an error, never a short TIFF with a 200.

The simulated board runs on its real-time clock here; forming each image is slowed down so
that the frames of a burst leave the 64-frame ring before the burst gets to them, as a
full-resolution burst over the network does on the default scenario.
"""

import io
import json
import threading
import time

import pytest
import tifffile
from fastapi.testclient import TestClient

from elphel_camd.api import create_app
from elphel_camd.service import CameraService
from elphel_host.camera.frames import read_tiff_pages
from elphel_sim.board import SimCameraBoard
from elphel_sim.scenarios import build

TOKEN = "test-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
SMALL = {"WOI_WIDTH": 64, "WOI_HEIGHT": 48, "WOI_LEFT": 1200, "WOI_TOP": 900}


@pytest.fixture
def slow_board(monkeypatch):
    """A board whose images take 120 ms each to form (the ring turns over in ~0.65 s)."""
    board = SimCameraBoard(build("default", seed=2), seed=2)
    form = board._image

    def slow_image(record):
        time.sleep(0.12)
        return form(record)

    monkeypatch.setattr(board, "_image", slow_image)
    return board


@pytest.fixture
def client(slow_board):
    camera = CameraService(slow_board)
    camera.set_params(0, SMALL)
    slow_board.sim_advance(frames=4)
    slow_board.start_clock()
    with TestClient(create_app(camera, token=TOKEN)) as c:
        yield c, camera
    camera.close()


def pages(body: bytes) -> list[tuple[tuple[int, ...], dict]]:
    with tifffile.TiffFile(io.BytesIO(body)) as tif:
        return [(p.shape, json.loads(p.description)) for p in tif.pages]


def test_burst_slower_than_the_ring_returns_every_frame(client):
    c, camera = client
    frame_s = 1 / camera.params(0)["FP1000S"] * 1000
    assert 64 * frame_s < 0.12 * 8  # the ring really turns over during this burst
    r = c.post("/api/v1/ports/0/capture", params={"count": 8}, headers=AUTH)
    assert r.status_code == 200
    got = pages(r.content)
    assert len(got) == 8
    frames = [meta["frame"] for _, meta in got]
    assert frames == list(range(frames[0], frames[0] + 8))
    assert int(r.headers["x-frame-number"]) == frames[0]
    for shape, meta in got:
        assert list(shape) == [meta["WOI_HEIGHT"], meta["WOI_WIDTH"]] == [48, 64]


def test_burst_outlasting_the_parameter_history_keeps_each_frames_metadata(client, monkeypatch):
    # At full resolution a burst can take longer than the 256 frames of parameter history.
    monkeypatch.setattr("elphel_camd.sequencer.HISTORY_FRAMES", 8)
    c, _ = client
    r = c.post("/api/v1/ports/0/capture", params={"count": 8}, headers=AUTH)
    assert r.status_code == 200
    got = pages(r.content)
    frames = [meta["frame"] for _, meta in got]
    assert frames == list(range(frames[0], frames[0] + 8))
    assert all(meta["WOI_WIDTH"] == 64 and meta["EXPOS"] > 0 for _, meta in got)


def test_concurrent_captures_of_one_frame_each_keep_its_metadata(client, monkeypatch):
    # Two captures hold the same next frame; the first to finish must not release the
    # other's hold (parameters of a frame long gone from the history).
    monkeypatch.setattr("elphel_camd.sequencer.HISTORY_FRAMES", 4)
    c, _ = client
    answers: list = []

    def capture(count: int) -> None:
        answers.append(c.post("/api/v1/ports/0/capture", params={"count": count}, headers=AUTH))

    threads = [threading.Thread(target=capture, args=(n,)) for n in (1, 3, 1, 2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert [r.status_code for r in answers] == [200] * 4, [r.text[:200] for r in answers]
    for r in answers:
        frames = [meta["frame"] for _, meta in pages(r.content)]
        assert frames == list(range(frames[0], frames[0] + len(frames)))
        assert all(meta["WOI_WIDTH"] == 64 for _, meta in pages(r.content))


def test_burst_from_a_frame_gone_from_the_ring_is_an_error(client):
    c, camera = client
    deadline = time.monotonic() + 10
    while camera.sequencers[0].this_frame < 100 and time.monotonic() < deadline:
        time.sleep(0.05)
    old = camera.sequencers[0].this_frame - 90  # the ring keeps the last 64
    r = c.post("/api/v1/ports/0/capture", params={"count": 4, "frame": old}, headers=AUTH)
    assert r.status_code == 404
    assert r.json()["error"] == "frame_not_available"


def test_window_change_during_a_burst_gives_each_page_its_shape(client):
    c, camera = client
    now = camera.sequencers[0].this_frame
    applied = camera.set_params(0, {"WOI_WIDTH": 32, "WOI_HEIGHT": 24}, frame=now + 8)
    r = c.post("/api/v1/ports/0/capture", params={"count": 6, "frame": applied - 3}, headers=AUTH)
    assert r.status_code == 200
    got = pages(r.content)
    assert [meta["frame"] for _, meta in got] == list(range(applied - 3, applied + 3))
    for shape, meta in got:
        expected = [24, 32] if meta["frame"] >= applied else [48, 64]
        assert list(shape) == expected
        assert [meta["WOI_HEIGHT"], meta["WOI_WIDTH"]] == expected
    images, metadata = read_tiff_pages(r.content)
    assert [m["frame"] for m in metadata] == list(range(applied - 3, applied + 3))
    assert [im.shape for im in images] == [tuple(s) for s, _ in got]
