"""The fast path of GET/PATCH params answers exactly what the FastAPI routes answer.

Two daemons on identical simulated boards, one with the fast path and one without, get
the same requests in the same order: plain ones (the fast path's), ones it hands on to the
routes (a query, no or a wrong token, an unknown port, a body the model refuses) and ones
whose work fails (a value out of the sensor's range). Every answer must be the same.
"""

import pytest
from fastapi.testclient import TestClient

from elphel_camd.api import create_app, fast_path
from elphel_camd.service import CameraService
from elphel_camd.store import ParamStore
from elphel_sim.board import SimCameraBoard
from elphel_sim.scenarios import build

TOKEN = "test-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
JSON = {**AUTH, "Content-Type": "application/json"}
P = "/api/v1/ports/0/params"

REQUESTS = [
    ("GET", P, AUTH, None),
    ("GET", P, {}, None),  # no token: 401 from the route
    ("GET", P, {"Authorization": "Bearer nope"}, None),
    ("GET", P, {"Authorization": f"Basic {TOKEN}"}, None),
    ("GET", P + "?frame=3", AUTH, None),
    ("GET", "/api/v1/ports/7/params", AUTH, None),  # no such port: 404
    ("PATCH", P, JSON, b'{"GAINR": 65536}'),
    ("GET", P, AUTH, None),
    ("PATCH", P, JSON, b'{"EXPOS": 2000, "GAING": 70000}'),
    ("PATCH", P, JSON, b'{"EXPOS": 1e400}'),  # not finite: 422
    ("PATCH", P, JSON, b'{"NOT_A_PARAM": 1}'),
    ("PATCH", P, JSON, b'{"WOI_WIDTH": 1000000}'),  # over the schema's range
    ("PATCH", P, JSON, b'{"WOI_WIDTH": 2}'),  # the schema allows it, the sensor does not
    ("PATCH", P, JSON, b"{not json"),
    ("PATCH", P, JSON, b""),
    ("PATCH", P, JSON, b"{}"),
    ("PATCH", P, JSON, b"[1, 2]"),
    ("PATCH", P, {**AUTH, "Content-Type": "text/plain"}, b'{"GAINR": 65537}'),
    ("PATCH", P, {"Content-Type": "application/json"}, b'{"GAINR": 65538}'),  # no token
    ("PATCH", P + "?ahead=2", JSON, b'{"GAINR": 65539}'),
    ("PATCH", P, JSON, b'{"TRIG": 4, "TRIG_PERIOD": 0}'),  # a parameter of every port
    ("PATCH", "/api/v1/ports/9/params", JSON, b'{"GAINR": 65540}'),
    ("GET", P, AUTH, None),
]


def daemon(
    tmp_path, name: str, *, fast: bool, public_reads: bool
) -> tuple[TestClient, CameraService]:
    board = SimCameraBoard(build("default", seed=2), seed=2)
    service = CameraService(board, store=ParamStore(tmp_path / name))
    board.sim_advance(frames=3)
    app = create_app(service, token=TOKEN, public_reads=public_reads, fast_path=fast)
    return TestClient(app), service


def answer(client: TestClient, method: str, path: str, headers: dict, body: bytes | None):
    r = client.request(method, path, headers=headers, content=body)
    return r.status_code, r.headers.get("content-type"), r.headers.get("allow"), r.content


@pytest.mark.parametrize("public_reads", [False, True])
def test_every_answer_is_the_routes_answer(tmp_path, public_reads):
    fast, fast_service = daemon(tmp_path, "fast", fast=True, public_reads=public_reads)
    slow, slow_service = daemon(tmp_path, "slow", fast=False, public_reads=public_reads)
    with fast, slow:
        for method, path, headers, body in REQUESTS:
            expected = answer(slow, method, path, headers, body)
            got = answer(fast, method, path, headers, body)
            assert got == expected, (method, path, headers, body)
            fast_service.board.sim_advance(frames=1)
            slow_service.board.sim_advance(frames=1)
    for service in (fast_service, slow_service):
        service.close()


def test_plain_requests_take_the_fast_path_and_the_others_the_routes(tmp_path, monkeypatch):
    calls = []
    real_read, real_write = fast_path.read_params, fast_path.write_params

    def read(*args):
        calls.append("read")
        return real_read(*args)

    def write(*args):
        calls.append("write")
        return real_write(*args)

    monkeypatch.setattr(fast_path, "read_params", read)
    monkeypatch.setattr(fast_path, "write_params", write)
    client, service = daemon(tmp_path, "fast", fast=True, public_reads=False)
    with client:
        assert client.get(P, headers=AUTH).status_code == 200
        assert client.patch(P, headers=JSON, content=b'{"GAINR": 65536}').status_code == 200
        assert calls == ["read", "write"]
        # What the routes answer (test_every_answer_is_the_routes_answer checks how).
        client.get(P + "?frame=1", headers=AUTH)
        assert client.get(P).status_code == 401
        assert client.patch(P, headers=JSON, content=b'{"NOT_A_PARAM": 1}').status_code == 422
        client.patch(P + "?ahead=1", headers=JSON, content=b'{"GAINR": 65537}')
        assert calls == ["read", "write"]
    service.close()
