"""The daemon's edges under hostile input (issue 41): each test is one promise of
docs/security.md or docs/rest-api.md, and fails if the daemon breaks it."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient

from elphel_camd.api import create_app
from elphel_camd.service import CameraService
from elphel_sim.board import SimCameraBoard
from elphel_sim.scenarios import build

TOKEN = "edge-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
JSON_AUTH = {**AUTH, "Content-Type": "application/json"}
SMALL = {"WOI_WIDTH": 64, "WOI_HEIGHT": 48, "WOI_LEFT": 1200, "WOI_TOP": 900}


@pytest.fixture
def camera():
    board = SimCameraBoard(build("default", seed=3), seed=3, noise=False)
    cam = CameraService(board)
    cam.set_params(0, SMALL)
    board.sim_advance(frames=4)
    yield cam
    cam.close()


@pytest.fixture
def client(camera):
    with TestClient(create_app(camera, token=TOKEN), raise_server_exceptions=False) as c:
        yield c


@pytest.mark.parametrize(
    ("path", "method", "body"),
    [
        ("/api/v1/ports/0/params", "PATCH", r'{"EXPOS": "\ud800"}'),
        ("/api/v1/ports/0/params", "PATCH", r'{"\ud800": 1}'),
        ("/api/v1/ports/0/params", "PATCH", r'"\udc00"'),
        ("/api/v1/ports/0/params", "PATCH", r'[1, "x\ud800y"]'),
        ("/api/v1/ports/0/registers/0x09", "PUT", r'{"value": "\udfff"}'),
    ],
)
def test_a_lone_surrogate_in_a_json_body_is_422_naming_it(client, path, method, body):
    before = client.get("/api/v1/ports/0/params", headers=AUTH).json()
    r = client.request(method, path, content=body.encode(), headers=JSON_AUTH)
    assert r.status_code == 422, r.text
    answer = json.loads(r.content.decode("utf-8"))  # strict UTF-8: no surrogate got through
    assert answer["error"] in ("parameter_range", "malformed_body")
    assert "\\ud800" in r.text or "\\udc00" in r.text or "\\udfff" in r.text
    assert client.get("/api/v1/ports/0/params", headers=AUTH).json() == before
