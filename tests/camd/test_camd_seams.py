"""The daemon's rooms: boards, service, store, frame metadata and the API's wiring.

Pins the seams the refactor made: what each module exports, the routes (paths, methods,
operation ids, statuses) and the service reached through a dependency rather than a
closure.
"""

import gc
import re
import time
import weakref

import numpy as np
import pytest
from fastapi.testclient import TestClient

from elphel_camd.api import create_app
from elphel_camd.api.deps import ApiOptions
from elphel_camd.boards import ENTRY_POINT_GROUP, Frame, I2CBoard, board_factories
from elphel_camd.frame_metadata import bayer_after_flips, frame_metadata
from elphel_camd.service import CameraService
from elphel_sim.board import SimCameraBoard
from elphel_sim.scenarios import build

# method, path, route function, statuses: as the API had them before the routers were split,
# with 409 (allowed by the schema, refused by the port's sensor or state) since, 503 when
# the event streams are at their limit, and the browser page's routes after them.
ROUTES_TABLE = """
GET /api/v1/info info 200,401,503
GET /api/v1/health health 200,503
GET /api/v1/ports/{port}/params get_params 200,401,404,422,503
PATCH /api/v1/ports/{port}/params patch_params 200,401,404,409,413,422,503
GET /api/v1/ports/{port}/frame get_frame 200,401,404,422
POST /api/v1/ports/{port}/capture capture 200,401,404,422,501,503,504
GET /api/v1/ports/{port}/registers list_registers 200,401,404,422
GET /api/v1/ports/{port}/registers/{addr} get_register 200,401,404,409,422,503
PUT /api/v1/ports/{port}/registers/{addr} put_register 200,401,404,409,413,422,503
GET /api/v1/events events 200,401,422,503
GET /api/v1/ports/{port}/params/schema get_param_schema 200,401,404,422,503
GET /api/v1/ports/{port}/preview get_preview 200,401,404,422,501,503,504
GET /api/v1/ports/{port}/preview.mjpeg get_preview_stream 200,401,404,422,429,501,503,504
GET /api/v1/ports/{port}/histogram get_histogram 200,401,404,422,501,503,504
GET / index 200
"""
# FastAPI's operationId: function name and path with non-word characters as "_", then method.
ROUTES = [
    (method, path, re.sub(r"\W", "_", name + path) + "_" + method.lower(), codes.split(","))
    for method, path, name, codes in (line.split() for line in ROUTES_TABLE.strip().splitlines())
]


@pytest.fixture(scope="module")
def service():
    svc = CameraService(SimCameraBoard(build("default", seed=2), seed=2, noise=False))
    yield svc
    svc.close()


def test_the_routes_and_their_order_are_those_of_the_contract(service):
    schema = create_app(service, token="t").openapi()
    found = [
        (method.upper(), path, op["operationId"], sorted(op["responses"]))
        for path, methods in schema["paths"].items()
        for method, op in methods.items()
    ]
    assert found == ROUTES
    assert schema["components"]["securitySchemes"] == {
        "HTTPBearer": {"type": "http", "description": "the daemon's token", "scheme": "bearer"}
    }


def test_the_service_and_options_reach_the_routes_through_app_state(service):
    app = create_app(service, token="secret", keepalive_s=3.0)
    assert app.state.service is service
    options = app.state.options
    assert isinstance(options, ApiOptions)
    assert (options.token.current(), options.public_reads, options.keepalive_s) == (
        "secret",
        False,
        3.0,
    )
    with TestClient(app) as client:
        assert client.get("/api/v1/info").status_code == 401
        answer = client.get("/api/v1/info", headers={"Authorization": "Bearer secret"})
        assert answer.status_code == 200 and answer.json()["board"] == service.board.name
        assert client.get("/api/v1/health").status_code == 200  # never protected


def test_two_apps_keep_their_own_service_and_token():
    first = CameraService(SimCameraBoard(build("default", seed=1), seed=1, noise=False))
    second = CameraService(SimCameraBoard(build("default", seed=1), seed=1, noise=False))
    try:
        a = TestClient(create_app(first, token="a"))
        b = TestClient(create_app(second, token="b"))
        url, patch = "/api/v1/ports/0/params", {"EXPOS": 1234}
        assert a.patch(url, json=patch, headers={"Authorization": "Bearer b"}).status_code == 401
        assert a.patch(url, json=patch, headers={"Authorization": "Bearer a"}).status_code == 200
        first.board.sim_advance(frames=4)
        second.board.sim_advance(frames=4)
        assert first.params(0)["EXPOS"] != second.params(0)["EXPOS"]
        got = b.get(url, headers={"Authorization": "Bearer b"}).json()
        assert got["EXPOS"] == second.params(0)["EXPOS"]
    finally:
        first.close()
        second.close()


def test_a_closed_and_dropped_app_is_freed_with_its_service_and_board():
    # FastAPI keeps every endpoint it has seen in a process-wide cache: an endpoint that
    # closed over its app would keep the app, the service and the board for good.
    service = CameraService(SimCameraBoard(build("default", seed=1), seed=1, noise=False))
    app = create_app(service, token="t")
    with TestClient(app) as client:
        assert client.get("/docs").status_code == 200
        assert client.get("/api/v1/info", headers={"Authorization": "Bearer t"}).status_code == 200
    service.close()
    gone = [weakref.ref(app), weakref.ref(service), weakref.ref(service.board)]
    del app, service, client
    # the service's frame thread, told to stop, may still be on its way out
    deadline = time.monotonic() + 2.0
    while any(ref() is not None for ref in gone) and time.monotonic() < deadline:
        gc.collect()
        time.sleep(0.05)
    assert [ref() for ref in gone] == [None, None, None]


def test_an_empty_token_is_refused(service):
    with pytest.raises(ValueError, match="token"):
        create_app(service, token="")


def test_the_board_registry_has_the_builtin_and_the_simulator():
    factories = board_factories()
    assert ENTRY_POINT_GROUP == "elphel_camd.boards"
    assert factories["i2c"] is I2CBoard
    assert "sim" in factories


@pytest.mark.parametrize(
    ("fliph", "flipv", "expected"),
    [(0, 0, "GRBG"), (1, 0, "RGGB"), (0, 1, "BGGR"), (1, 1, "GBRG")],
)
def test_bayer_after_flips(fliph, flipv, expected):
    assert bayer_after_flips("GRBG", fliph, flipv) == expected
    assert bayer_after_flips(None, fliph, flipv) is None


def test_frame_metadata_names_the_frame_and_its_parameters():
    got = Frame(image=np.zeros((4, 6), np.uint16), frame=7, timestamp_ns=123)
    params = {"EXPOS": 100, "FLIPH": 1, "FLIPV": 0, "WOI_HEIGHT": 4}
    meta = frame_metadata(got, port=2, sensor="MT9P006", bayer="GRBG", params=params)
    assert meta == {
        "frame": 7,
        "timestamp_ns": 123,
        "port": 2,
        "sensor": "MT9P006",
        "bayer": "RGGB",
        **params,
    }
    assert list(meta)[:5] == ["frame", "timestamp_ns", "port", "sensor", "bayer"]


def test_frame_metadata_of_a_photo_finish_composite():
    params = {"PF_HEIGHT": 2, "WOI_HEIGHT": 8, "FP1000S": 50_000}
    got = Frame(image=np.zeros((8, 4), np.uint16), frame=1, timestamp_ns=0)
    meta = frame_metadata(got, port=0, sensor="MT9P006", bayer=None, params=params)
    assert (meta["pf_strips"], meta["pf_strip_period_ns"]) == (4, 20_000_000)
    timed = Frame(image=got.image, frame=1, timestamp_ns=0, strip_period_ns=5)
    meta = frame_metadata(timed, port=0, sensor="MT9P006", bayer=None, params=params)
    assert meta["pf_strip_period_ns"] == 5
