"""The daemon's edges under hostile input (issue 41): each test is one promise of
docs/security.md or docs/rest-api.md, and fails if the daemon breaks it."""

from __future__ import annotations

import base64
import hashlib
import json
import re

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


def _csp(headers) -> dict[str, str]:
    """The directives of a Content-Security-Policy header."""
    policy = headers["content-security-policy"]
    return {d.split()[0]: d.strip() for d in policy.split(";") if d.strip()}


@pytest.mark.parametrize("path", ["/", "/web/index.html", "/docs"])
def test_every_html_answer_has_the_csp_and_forbids_framing(client, path):
    r = client.get(path)
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    directives = _csp(r.headers)
    assert directives["frame-ancestors"] == "frame-ancestors 'none'"
    assert "*" not in r.headers["content-security-policy"]
    assert "'unsafe-inline'" not in r.headers["content-security-policy"]
    assert r.headers["x-frame-options"] == "DENY"


def test_the_docs_page_style_is_the_one_its_csp_allows(client):
    r = client.get("/docs")
    styles = re.findall(r"<style>(.*?)</style>", r.text, flags=re.S)
    assert len(styles) == 1 and "<script" not in r.text
    digest = base64.b64encode(hashlib.sha256(styles[0].encode()).digest()).decode()
    assert _csp(r.headers)["style-src"] == f"style-src 'sha256-{digest}'"


@pytest.mark.parametrize(
    ("method", "path", "headers", "status"),
    [
        ("GET", "/api/v1/health", {}, 200),
        ("GET", "/api/v1/info", AUTH, 200),
        ("GET", "/api/v1/info", {}, 401),
        ("GET", "/api/v1/ports/0/params", AUTH, 200),  # the fast path
        ("GET", "/api/v1/ports/9/params", AUTH, 404),
        ("GET", "/openapi.json", {}, 200),
        ("GET", "/web/main.js", {}, 200),
        ("GET", "/nowhere", {}, 404),
        ("PATCH", "/api/v1/ports/0/params", {**JSON_AUTH, "Content-Length": "999999"}, 413),
    ],
)
def test_every_answer_says_nosniff_and_no_referrer(client, method, path, headers, status):
    r = client.request(method, path, headers=headers)
    assert r.status_code == status, r.text
    assert r.headers["x-content-type-options"] == "nosniff"
    assert r.headers["referrer-policy"] == "no-referrer"
