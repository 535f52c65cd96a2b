"""The daemon's REST API on the simulated board: validation, registers, health, bursts,
security and concurrency (in process, through FastAPI's test client)."""

import io
import json
import threading

import numpy as np
import pytest
import tifffile
from fastapi.testclient import TestClient

from elphel_camd.api import create_app
from elphel_camd.params import PARAMS
from elphel_camd.service import CameraService
from elphel_camd.store import ParamStore, last_journal_line
from elphel_sim.board import SimCameraBoard
from elphel_sim.scenarios import PortSpec, build

TOKEN = "test-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
SMALL = {"WOI_WIDTH": 64, "WOI_HEIGHT": 48, "WOI_LEFT": 1200, "WOI_TOP": 900}


def two_port_board() -> SimCameraBoard:
    scenario = build("default", seed=3)
    scenario.ports.append(PortSpec("MT9P006", "cam0", scenario.ports[0].intrinsics))
    return SimCameraBoard(scenario, seed=3)


@pytest.fixture
def board():
    return SimCameraBoard(build("default", seed=1), seed=1)


@pytest.fixture
def camera(board, tmp_path):
    cam = CameraService(board, store=ParamStore(tmp_path / "params"))
    cam.set_params(0, SMALL)
    board.sim_advance(frames=4)
    yield cam
    cam.close()


@pytest.fixture
def client(camera):
    # Reads public: these tests are about the answers; tests/camd/test_security.py checks
    # that reads need the token by default.
    with TestClient(create_app(camera, token=TOKEN, public_reads=True)) as c:
        yield c


@pytest.fixture(scope="module")
def shared_client(tmp_path_factory):
    """One camera for the tests that must leave it unchanged."""
    board = SimCameraBoard(build("default", seed=1), seed=1)
    cam = CameraService(board, store=ParamStore(tmp_path_factory.mktemp("params")))
    cam.set_params(0, SMALL)
    board.sim_advance(frames=4)
    with TestClient(create_app(cam, token=TOKEN, public_reads=True)) as c:
        yield c
    cam.close()


def test_openapi_states_every_parameter_with_unit_and_limits(client):
    schema = client.get("/openapi.json").json()["components"]["schemas"]
    patch, params = schema["ParamsPatch"], schema["Params"]
    assert patch["additionalProperties"] is False
    for name, spec in PARAMS.items():
        prop = params["properties"][name]
        assert (prop["minimum"], prop["maximum"], prop["unit"]) == (
            spec.minimum,
            spec.maximum,
            spec.unit,
        )
        assert (name in patch["properties"]) is not spec.read_only
        assert "default" not in prop


# Values every sensor rejects and that the OpenAPI schema refuses (422), and values the
# schema allows but the MT9P006 refuses (409: its own limits, the window inside the sensor).
SCHEMA_INVALID = {
    "WOI_WIDTH": [3],
    "WOI_HEIGHT": [5],
    "WOI_LEFT": [1],
    "WOI_TOP": [3],
    "FLIPH": [2],
    "FLIPV": [2],
    "VEXPOS": [0],
    "TRIG": [1, 5, 19],
    "PF_HEIGHT": [3, 1],
    "FPSFLAGS": [4],
}
SENSOR_REFUSED = {
    "WOI_WIDTH": [2594],
    "WOI_HEIGHT": [1946],
    "WOI_LEFT": [2592],
    "WOI_TOP": [1944],
    "EXPOS": [10**9],
    "TRIG_PERIOD": [2, 255],
    "TRIG_MASTER": [1, 3],
    "PF_HEIGHT": [2000],
}


def invalid_values(name):
    """(value, status) pairs a writable parameter refuses on port 0 (an MT9P006)."""
    spec = PARAMS[name]
    values = [spec.minimum - 1, spec.maximum + 1, "12", 1.5, None, True, [1]]
    values += SCHEMA_INVALID.get(name, [])
    return [(v, 422) for v in values] + [(v, 409) for v in SENSOR_REFUSED.get(name, [])]


WRITABLE = [n for n, s in PARAMS.items() if not s.read_only]


@pytest.mark.parametrize("name", WRITABLE)
def test_every_invalid_value_is_422_or_409_naming_it_and_changes_nothing(shared_client, name):
    client = shared_client
    before = client.get("/api/v1/ports/0/params", headers=AUTH).json()
    valid = {"GAINR": 0x18000} if name == "GAINB" else {"GAINB": 0x18000}  # must not stick
    for value, status in invalid_values(name):
        r = client.patch("/api/v1/ports/0/params", json={**valid, name: value}, headers=AUTH)
        assert r.status_code == status, (name, value, r.text)
        body = r.json()
        assert body["parameter"] == name, body
        assert body["value"] == value or body["value"] == str(value), body
        assert body["allowed"] and name in body["detail"], body
    assert client.get("/api/v1/ports/0/params", headers=AUTH).json() == before


def test_read_only_unknown_and_malformed_bodies_are_422(client):
    for body, parameter, error in (
        ({"FRAME": 5}, "FRAME", "unknown_parameter"),
        ({"SENSOR": 1}, "SENSOR", "unknown_parameter"),
        ({"EXPOSURE": 5}, "EXPOSURE", "unknown_parameter"),
        ({"EXPOS": -1}, "EXPOS", "parameter_range"),
        ([1, 2], "body", "malformed_body"),
        ("x", "body", "malformed_body"),
    ):
        r = client.patch("/api/v1/ports/0/params", json=body, headers=AUTH)
        assert r.status_code == 422, r.text
        assert (r.json()["parameter"], r.json()["error"]) == (parameter, error), r.text
    r = client.patch("/api/v1/ports/0/params", json={"FRAME": 5}, headers=AUTH)
    assert r.json()["allowed"] == "nothing: it is read-only"
    # A body that is not JSON, or not even UTF-8, is malformed: no parameter's range error.
    for method, path in (
        ("PATCH", "/api/v1/ports/0/params"),
        ("PUT", "/api/v1/ports/0/registers/1"),
    ):
        for content in (b"{not json", b'{"EXPOS": 5\xff}'):
            r = client.request(
                method, path, content=content, headers={**AUTH, "content-type": "application/json"}
            )
            assert r.status_code == 422, (method, content, r.text)
            body = r.json()
            assert body["error"] == "malformed_body" and body["parameter"] == "body", body
            assert body["allowed"].startswith("a JSON object"), body


def test_patch_persists_every_accepted_change(client, tmp_path):
    r = client.patch("/api/v1/ports/0/params", json={"EXPOS": 5000, "GAINR": 0x20000}, headers=AUTH)
    assert r.status_code == 200
    line = last_journal_line(tmp_path / "params" / "port0.log")
    assert line is not None  # in the journal before the answer
    saved = json.loads(line)
    assert saved["sensor"] == "MT9P006"
    assert saved["params"]["EXPOS"] == r.json()["params"]["EXPOS"]
    assert saved["params"]["GAINR"] == 0x20000
    assert "VEXPOS" not in saved["params"] and "FRAME" not in saved["params"]


def test_saved_parameters_are_restored_at_start(tmp_path):
    store = ParamStore(tmp_path / "params")
    first = CameraService(SimCameraBoard(build("default", seed=1), seed=1), store=store)
    first.set_params(0, {**SMALL, "EXPOS": 4321, "FLIPH": 1})
    expected = first.params(0, frame=first.sequencer(0).this_frame + 14)
    first.close()
    second = CameraService(
        SimCameraBoard(build("default", seed=1), seed=1), store=ParamStore(tmp_path / "params")
    )
    got = second.params(0)
    second.close()
    for name in (*SMALL, "EXPOS", "VEXPOS", "FLIPH", "GAINR"):
        assert got[name] == expected[name], name


def test_ring_buffer_serves_a_frame_after_the_fact(client, board):
    first = client.post("/api/v1/ports/0/capture", headers=AUTH)
    n = int(first.headers["X-Frame-Number"])
    board.sim_advance(frames=10)
    again = client.post(f"/api/v1/ports/0/capture?frame={n}", headers=AUTH)
    assert again.status_code == 200
    assert again.content == first.content
    board.sim_advance(frames=80)  # past the 64-frame ring
    gone = client.post(f"/api/v1/ports/0/capture?frame={n}", headers=AUTH)
    assert gone.status_code == 404 and gone.json()["error"] == "frame_not_available"
    future = client.post(f"/api/v1/ports/0/capture?frame={n + 10**6}", headers=AUTH)
    assert future.status_code == 404


def test_burst_is_a_multipage_tiff_of_consecutive_frames(client):
    r = client.post("/api/v1/ports/0/capture?count=5", headers=AUTH)
    assert r.status_code == 200 and r.headers["content-type"] == "image/tiff"
    with tifffile.TiffFile(io.BytesIO(r.content)) as tif:
        stack = tif.asarray()
        metas = [json.loads(p.description) for p in tif.pages]
    assert stack.shape == (5, 48, 64) and stack.dtype == np.uint16
    frames = [m["frame"] for m in metas]
    assert frames == list(range(frames[0], frames[0] + 5))
    assert int(r.headers["X-Frame-Number"]) == frames[0]
    assert all(m["WOI_WIDTH"] == 64 and m["sensor"] == "MT9P006" for m in metas)
    # The same frames again, from the ring buffer.
    again = client.post(f"/api/v1/ports/0/capture?count=5&frame={frames[0]}", headers=AUTH)
    assert again.content == r.content
    assert client.post("/api/v1/ports/0/capture?count=0", headers=AUTH).status_code == 422


def test_registers_read_write_and_validation(client, camera):
    table = client.get("/api/v1/ports/0/registers").json()
    gain = next(r for r in table if r["name"] == "green1_gain")
    r = client.get(f"/api/v1/ports/0/registers/0x{gain['address']:02x}")
    assert r.status_code == 200 and r.json()["name"] == "green1_gain"
    assert client.get(f"/api/v1/ports/0/registers/{gain['address']}").json() == r.json()
    w = client.put(
        f"/api/v1/ports/0/registers/0x{gain['address']:x}", json={"value": 0x10}, headers=AUTH
    )
    assert w.status_code == 200, w.text
    assert client.get(f"/api/v1/ports/0/registers/{gain['address']}").json()["value"] == 0x10
    assert camera.board.chips[0].values[gain["address"]] == 0x10
    unknown = client.get("/api/v1/ports/0/registers/0xee")  # allowed by the schema, not the chip
    assert unknown.status_code == 404 and unknown.json()["parameter"] == "address"
    assert unknown.json()["error"] == "no_such_register"
    assert "0xee" in unknown.json()["detail"]
    over = client.put(
        f"/api/v1/ports/0/registers/0x{gain['address']:x}",
        json={"value": gain["maximum"] + 1},
        headers=AUTH,
    )
    assert over.status_code == 409
    assert over.json()["parameter"] == "green1_gain"
    assert over.json()["value"] == gain["maximum"] + 1 and over.json()["allowed"]
    chip = next(r for r in table if r["access"] == "ro")
    ro = client.put(f"/api/v1/ports/0/registers/{chip['address']}", json={"value": 1}, headers=AUTH)
    assert ro.status_code == 409 and ro.json()["parameter"] == chip["name"]
    assert client.put("/api/v1/ports/0/registers/0x35", json={"value": 1}).status_code == 401
    bad = client.get("/api/v1/ports/0/registers/zz")
    assert bad.status_code == 422 and bad.json()["parameter"] == "addr"


def test_i2c_fault_is_503_on_its_port_while_the_other_port_serves():
    board = two_port_board()
    service = CameraService(board)
    try:
        with TestClient(create_app(service, token=TOKEN, public_reads=True)) as c:
            assert c.get("/api/v1/health").json()["status"] == "ok"
            board.bus(0).sim_stuck()
            h = c.get("/api/v1/health")
            assert h.status_code == 503
            body = h.json()
            assert body["status"] == "degraded" and body["error"] == "i2c"
            assert [p["ok"] for p in body["ports"]] == [False, True]
            r = c.get("/api/v1/ports/0/registers/0x35")
            assert r.status_code == 503 and r.json()["error"] == "i2c"
            assert c.get("/api/v1/ports/1/registers/0x35").status_code == 200
            assert (
                c.patch("/api/v1/ports/1/params", json={"EXPOS": 2000}, headers=AUTH).status_code
                == 200
            )
            assert c.get("/api/v1/ports/1/params").status_code == 200
            board.bus(0).sim_stuck(False)
            assert c.get("/api/v1/health").status_code == 200
    finally:
        service.close()


def test_concurrent_patches_never_interleave(client, camera):
    """Two clients set the window to two consistent sets; every state seen is one of them."""
    sets = [
        {"WOI_WIDTH": 64, "WOI_HEIGHT": 48, "EXPOS": 3000},
        {"WOI_WIDTH": 128, "WOI_HEIGHT": 96, "EXPOS": 6000},
    ]
    errors = []

    def writer(values):
        for _ in range(25):
            r = client.patch("/api/v1/ports/0/params", json=values, headers=AUTH)
            if r.status_code != 200:
                errors.append(r.text)

    threads = [threading.Thread(target=writer, args=(s,)) for s in sets]
    for t in threads:
        t.start()
    seq = camera.sequencer(0)
    seen = []
    while any(t.is_alive() for t in threads):
        state = seq.state_at(seq.this_frame + 14)
        seen.append((state["WOI_WIDTH"], state["WOI_HEIGHT"]))
    for t in threads:
        t.join()
    assert not errors
    assert set(seen) <= {(64, 48), (128, 96)}


def test_security_token_read_protection_cors_and_size_limit(camera):
    with TestClient(create_app(camera, token=TOKEN)) as c:
        assert c.get("/api/v1/ports/0/params").status_code == 401
        assert c.get("/api/v1/events").status_code == 401
        assert c.get("/api/v1/ports/0/params", headers=AUTH).status_code == 200
        assert c.get("/api/v1/health").status_code == 200
    with TestClient(create_app(camera, token=TOKEN, max_body_bytes=2048)) as c:
        assert c.get("/api/v1/ports/0/params").status_code == 401  # reads need it by default
        assert c.get("/api/v1/ports/0/params", headers=AUTH).status_code == 200
        r = c.patch("/api/v1/ports/0/params", content=b"{" + b" " * 4096 + b"}", headers=AUTH)
        assert r.status_code == 413
        for method in ("patch", "put"):
            path = "/api/v1/ports/0/params" if method == "patch" else "/api/v1/ports/0/registers/1"
            assert getattr(c, method)(path, json={"EXPOS": 1}).status_code == 401
        pre = c.options(
            "/api/v1/ports/0/params",
            headers={"Origin": "http://evil.example", "Access-Control-Request-Method": "PATCH"},
        )
        assert "access-control-allow-origin" not in pre.headers
        got = c.get("/api/v1/info", headers={"Origin": "http://evil.example"})
        assert "access-control-allow-origin" not in got.headers


def test_events_publish_frames_changes_and_errors(camera, board):
    sub = camera.events.subscribe()
    camera.set_params(0, {"EXPOS": 2500})
    board.sim_advance(frames=2)
    board.bus(0).sim_stuck()
    camera.set_params(0, {"GAINR": 0x20000})
    board.sim_advance(frames=3)
    board.bus(0).sim_stuck(False)
    events = []
    while (e := sub.get_blocking(0.01)) is not None:
        events.append(e)
    camera.events.unsubscribe(sub)
    types = [e.type for e in events]
    assert types[0] == "params" and events[0].data["changes"] == {"EXPOS": 2500}
    frames = [e.data["frame"] for e in events if e.type == "frame"]
    assert frames == list(range(frames[0], frames[0] + 5))
    assert any(e.type == "error" and "port 0" in e.data["detail"] for e in events)


def test_a_slow_subscriber_loses_old_events_and_never_blocks(camera, board):
    camera.events.queue_size = 3
    sub = camera.events.subscribe(["frame"])
    board.sim_advance(frames=10)  # nobody reads: must not block
    got = [sub.get_blocking(0.01) for _ in range(3)]
    assert sub.dropped == 7
    assert [e.data["frame"] for e in got if e] == [e.data["frame"] for e in got if e][:3]
    assert sub.get_blocking(0.01) is None
    camera.events.unsubscribe(sub)


@pytest.mark.parametrize("query", ["frame=%2B2&ahead=2", "frame=9&ahead=2", "frame=9&ahead=0"])
def test_frame_and_ahead_together_are_refused_and_change_nothing(client, camera, query):
    before = camera.params(0, frame=camera.sequencer(0).this_frame + 14)
    r = client.patch(f"/api/v1/ports/0/params?{query}", json={"GAINB": 0x18000}, headers=AUTH)
    assert r.status_code == 409
    assert r.json()["error"] == "unsupported" and "not both" in r.json()["detail"]
    assert camera.params(0, frame=camera.sequencer(0).this_frame + 14) == before
    with pytest.raises(ValueError, match="not both"):
        camera.set_params(0, {"GAINB": 0x18000}, frame=9, ahead=2)
