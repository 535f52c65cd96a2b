"""The real daemon application on the simulated board, through FastAPI's test client."""

import io
import json
import time

import numpy as np
import pytest
import tifffile
from fastapi.testclient import TestClient

from elphel_camd.api import create_app
from elphel_camd.boards import board_factories
from elphel_camd.service import CameraService
from elphel_sim.board import SimCameraBoard, make_sim_board
from elphel_sim.scenarios import build

TOKEN = "test-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture
def board():
    sim = SimCameraBoard(build("default", seed=1), seed=1)
    yield sim
    sim.close()


@pytest.fixture
def client(board):
    service = CameraService(board)
    with TestClient(create_app(service, token=TOKEN, public_reads=True)) as c:
        yield c
    service.close()


def test_info_reports_the_sensor_read_over_simulated_i2c(client, board):
    board.bus(0).log_transfers = True
    info = client.get("/api/v1/info").json()
    assert info["board"] == "sim"
    (port,) = info["ports"]
    assert port["port"] == 0
    assert port["sensor"]["model"] == "MT9P006"
    assert port["sensor"]["chip_id"] == 0x1801
    # The chip id was read now, over the bus, as a combined write+read to 0x48.
    assert (0x48, "w", b"\x00") in board.bus(0).transfers
    assert (0x48, "r", b"\x18\x01") in board.bus(0).transfers


def test_capture_returns_16bit_tiff_with_metadata(client):
    r = client.post("/api/v1/ports/0/capture", headers=AUTH)
    assert r.status_code == 200
    assert r.headers["content-type"] == "image/tiff"
    with tifffile.TiffFile(io.BytesIO(r.content)) as tif:
        image = tif.asarray()
        meta = json.loads(tif.pages.first.description)
    assert image.dtype == np.uint16 and image.shape == (1944, 2592)
    assert 0 < image.mean() < 4095
    assert int(r.headers["X-Frame-Number"]) == meta["frame"]
    for key in ("frame", "timestamp_ns", "port", "sensor", "bayer", "EXPOS", "GAINR", "WOI_WIDTH"):
        assert key in meta
    assert meta["sensor"] == "MT9P006" and meta["bayer"] == "GRBG"
    assert (meta["WOI_WIDTH"], meta["WOI_HEIGHT"]) == (2592, 1944)
    second = client.post("/api/v1/ports/0/capture", headers=AUTH)
    assert int(second.headers["X-Frame-Number"]) == meta["frame"] + 1


@pytest.mark.parametrize(
    "headers", [{}, {"Authorization": "Bearer wrong"}, {"Authorization": TOKEN}]
)
def test_writes_without_the_token_get_401(client, headers):
    r = client.post("/api/v1/ports/0/capture", headers=headers)
    assert r.status_code == 401
    assert "Bearer" in r.json()["detail"]
    assert r.headers["www-authenticate"] == "Bearer"


def test_unknown_port_is_404_and_bad_port_is_422(client):
    r = client.post("/api/v1/ports/7/capture", headers=AUTH)
    assert r.status_code == 404
    assert "port 7" in r.json()["detail"]
    assert client.post("/api/v1/ports/x/capture", headers=AUTH).status_code == 422


def test_patch_params_sets_window_and_gain_through_rest(client):
    body = {"WOI_WIDTH": 200, "WOI_HEIGHT": 100, "WOI_LEFT": 1000, "WOI_TOP": 700}
    r = client.patch("/api/v1/ports/0/params", json=body, headers=AUTH)
    assert r.status_code == 200, r.text
    target = r.json()["frame"]
    assert r.json()["params"]["WOI_WIDTH"] == 200
    shapes = []
    while True:
        c = client.post("/api/v1/ports/0/capture", headers=AUTH)
        frame = int(c.headers["X-Frame-Number"])
        shapes.append(tifffile.imread(io.BytesIO(c.content)).shape)
        if frame >= target:
            break
    assert shapes[-1] == (100, 200)
    now = client.get("/api/v1/ports/0/frame").json()["frame"]
    r = client.patch("/api/v1/ports/0/params?frame=%2B5", json={"GAINR": 0x20000}, headers=AUTH)
    assert r.json()["frame"] == now + 5
    r = client.patch("/api/v1/ports/0/params?ahead=4", json={"GAINB": 0x20000}, headers=AUTH)
    assert r.json()["frame"] == now + 4
    assert client.get(f"/api/v1/ports/0/params?frame={now + 5}").json()["GAINR"] == 0x20000


def test_patch_errors_are_409_or_422_with_the_parameter_value_and_range(client):
    # 409: the schema allows it, the sensor (or the frame schedule) refuses it.
    r = client.patch("/api/v1/ports/0/params", json={"WOI_WIDTH": 3000}, headers=AUTH)
    assert r.status_code == 409
    body = r.json()
    assert body["parameter"] == "WOI_WIDTH" and body["value"] == 3000
    assert "2..2592" in body["allowed"] and "WOI_WIDTH" in body["detail"]
    r = client.patch("/api/v1/ports/0/params?ahead=1", json={"EXPOS": 100}, headers=AUTH)
    assert r.status_code == 409 and r.json()["error"] == "frame_too_late"
    r = client.patch("/api/v1/ports/0/params?ahead=15", json={"EXPOS": 100}, headers=AUTH)
    assert r.status_code == 409 and r.json()["error"] == "frame_too_early"
    r = client.patch("/api/v1/ports/0/params?frame=soon", json={"EXPOS": 100}, headers=AUTH)
    assert r.status_code == 422 and r.json()["parameter"] == "frame"
    r = client.patch("/api/v1/ports/0/params", json={"EXPOS": 100})
    assert r.status_code == 401


def test_sim_board_is_registered_for_the_daemon():
    factories = board_factories()
    assert factories["sim"] is make_sim_board
    assert "i2c" in factories


def test_the_daemons_sim_board_starts_no_frame_before_the_daemon_sees_it():
    # Frame 1 used to start before the service subscribed: the first capture then named a
    # frame whose parameters the daemon never recorded (404, "no longer kept").
    board = make_sim_board()
    try:
        time.sleep(0.2)
        assert board.fpga[0].frame == 0
        service = CameraService(board)
        deadline = time.monotonic() + 10
        while service.sequencers[0].this_frame < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert service.params(0, frame=1)["FRAME"] == 1
    finally:
        board.close()


def test_stuck_bus_surfaces_as_503_naming_the_port(board):
    with TestClient(create_app(CameraService(board), token=TOKEN, public_reads=True)) as c:
        board.bus(0).sim_stuck()
        r = c.get("/api/v1/info")
        assert r.status_code == 503
        assert "port 0" in r.json()["detail"] and "0x48" in r.json()["detail"]
        board.bus(0).sim_stuck(False)
        assert c.get("/api/v1/info").status_code == 200


def test_missing_sensor_reported_as_empty_port():
    from elphel_sim.scenarios import PortSpec

    scenario = build("default", seed=0)
    scenario.ports.append(PortSpec(None, "cam0", scenario.ports[0].intrinsics))
    camera = CameraService(SimCameraBoard(scenario))
    try:
        info = camera.info()
        assert info["ports"][1]["sensor"] is None
        with TestClient(create_app(camera, token=TOKEN)) as c:
            r = c.post("/api/v1/ports/1/capture", headers=AUTH)
            assert r.status_code == 404 and "no sensor" in r.json()["detail"]
    finally:
        camera.close()
