"""The mixed scenario's Lepton served through VoSPI: the board's frames, read by the reader."""

import io
import json
import time

import httpx
import numpy as np
import pytest
import tifffile
from fastapi import FastAPI
from fastapi.testclient import TestClient

from elphel_camd.service import CameraService
from elphel_sim.board import SimCameraBoard
from elphel_sim.lepton_vospi import lepton_ports, vospi_board, vospi_fault_router
from elphel_sim.pytest_plugin import start_rig, stop_rig
from elphel_sim.scenarios import build

LEPTON_PORT = 2


@pytest.fixture
def mixed_board():
    board = SimCameraBoard(build("mixed", seed=1), seed=1, noise=False)
    camera = CameraService(board)
    board.start_clock(time_scale=1.0)
    try:
        yield board, camera
    finally:
        camera.close()


def test_each_vospi_frame_is_the_ports_frame_of_the_same_number(mixed_board):
    board, camera = mixed_board
    assert lepton_ports(board) == [LEPTON_PORT]
    camera.set_params(LEPTON_PORT, {"WOI_HEIGHT": 122})  # telemetry: the frame counter
    vospi = vospi_board(board, LEPTON_PORT, seed=1)
    try:
        got = [vospi.board.capture(0, timeout_s=10) for _ in range(4)]
        counted = [f for f in got if "telemetry" in f.metadata]
        assert len(counted) >= 3
        for frame in counted:
            formed, _ = camera.capture(LEPTON_PORT, frame=frame.frame)
            np.testing.assert_array_equal(frame.image, formed.image[:120])
        assert vospi.board.port_status(0)["state"] == "streaming"
    finally:
        vospi.board.close()


def test_a_vospi_fault_is_recovered_from_by_the_reader(mixed_board):
    board, _ = mixed_board
    vospi = vospi_board(board, LEPTON_PORT, seed=1)
    try:
        before = vospi.board.capture(0, timeout_s=10).frame
        vospi.stream.sim_lose_sync(vospi.stream.t)
        after = [vospi.board.capture(0, timeout_s=10).frame for _ in range(3)]
        assert before < after[0] < after[1] < after[2]
        (fault,) = vospi.stream.faults
        assert fault.kind == "lost_sync" and fault.end_s - fault.start_s < 0.3  # cured
        assert vospi.board.frames.health()["resyncs"] == 1
    finally:
        vospi.board.close()


def test_vospi_faults_are_injected_over_the_inspection_endpoint(mixed_board):
    board, _ = mixed_board
    vospi = vospi_board(board, LEPTON_PORT, seed=1)
    app = FastAPI()
    app.include_router(vospi_fault_router([vospi]))
    try:
        with TestClient(app) as c:
            before = vospi.board.capture(0, timeout_s=10).frame
            r = c.post(f"/lepton/{LEPTON_PORT}/faults", json={"kind": "stall", "duration_s": 0.5})
            assert r.status_code == 200, r.text
            deadline = time.monotonic() + 30
            while not any(
                f["end_s"] for f in c.get(f"/lepton/{LEPTON_PORT}/faults").json()["faults"]
            ):
                assert time.monotonic() < deadline, "the stall never ended"
                time.sleep(0.1)
            (fault,) = c.get(f"/lepton/{LEPTON_PORT}/faults").json()["faults"]
            assert fault["kind"] == "stall" and fault["end_s"] - fault["start_s"] == pytest.approx(
                0.5
            )
            assert vospi.board.capture(0, timeout_s=10).frame > before
            assert c.post("/lepton/3/faults", json={"kind": "stall"}).status_code == 404
            assert c.post(f"/lepton/{LEPTON_PORT}/faults", json={"kind": "melt"}).status_code == 422
    finally:
        vospi.board.close()


@pytest.mark.slow
def test_elphel_sim_up_announces_a_vospi_daemon_per_lepton_port():
    started = start_rig(scenario="mixed")
    try:
        line = json.dumps(started.rig.__dict__)
        assert len(started.rig.lepton_urls) == 1, line
        url, token = started.rig.lepton_urls[0], started.rig.lepton_tokens[0]
        headers = {"Authorization": f"Bearer {token}"}
        r = httpx.post(f"{url}/api/v1/ports/0/capture", headers=headers, timeout=30)
        assert r.status_code == 200, r.text
        with tifffile.TiffFile(io.BytesIO(r.content)) as tif:
            assert tif.pages[0].asarray().shape == (120, 160)
        health = httpx.get(f"{url}/api/v1/health", headers=headers, timeout=30).json()
        assert health["board"] == "lepton"
        assert health["ports"][0]["stream"]["path"] == "simulated spidev of port 2"
        r = httpx.post(f"{started.rig.sim_url}/lepton/2/faults", json={"kind": "lose_sync"})
        assert r.status_code == 200, r.text
    finally:
        stop_rig(started.proc)
    plain = start_rig(scenario="default")
    try:
        assert plain.rig.lepton_urls == ()
    finally:
        stop_rig(plain.proc)
