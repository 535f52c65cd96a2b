"""The daemon's edges under hostile input (issue 41): each test is one promise of
docs/security.md or docs/rest-api.md, and fails if the daemon breaks it."""

from __future__ import annotations

import base64
import hashlib
import io
import json
import logging
import re

import numpy as np
import pytest
import tifffile
from fastapi.testclient import TestClient

from elphel_camd.api import create_app, tiff
from elphel_camd.api.deps import FailedAuth, LogLimit
from elphel_camd.sequencer import MAX_AHEAD
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


@pytest.mark.parametrize("public_reads", [False, True])
@pytest.mark.parametrize("order", ["wrong-right", "right-wrong", "right-right"])
def test_two_authorization_headers_are_refused_on_every_path(camera, public_reads, order):
    app = create_app(camera, token=TOKEN, public_reads=public_reads)
    app.state.options.failed = FailedAuth(base_s=0.0, max_s=0.0)
    values = {"wrong": b"Bearer not-the-token", "right": f"Bearer {TOKEN}".encode()}
    twice = [(b"authorization", values[name]) for name in order.split("-")]
    body = json.dumps({"EXPOS": 1000}).encode()
    with TestClient(app) as c:
        # PATCH goes through the fast path, the others through the routes: one rule.
        for method, path, content in (
            ("GET", "/api/v1/info", None),
            ("GET", "/api/v1/ports/0/params", None),
            ("PATCH", "/api/v1/ports/0/params", body),
            ("POST", "/api/v1/ports/0/capture", None),
        ):
            headers = [(b"content-type", b"application/json"), *twice]
            r = c.request(method, path, content=content, headers=headers)
            expected = 200 if public_reads and method == "GET" else 401
            assert r.status_code == expected, (method, path, r.text)
            if expected == 401:
                assert "2 Authorization headers" in r.json()["detail"]
        assert c.patch("/api/v1/ports/0/params", content=body, headers=JSON_AUTH).status_code == 200


def test_failed_token_lines_are_rate_limited_and_say_how_many_were_left_out(camera, caplog):
    app = create_app(camera, token=TOKEN)
    app.state.options.failed = FailedAuth(base_s=0.0, max_s=0.0)
    limit = app.state.options.auth_log = LogLimit(lines=3, window_s=600.0)
    wrong = {"Authorization": "Bearer guess"}
    with TestClient(app) as c, caplog.at_level(logging.INFO, "elphel_camd.auth"):
        for _ in range(50):
            assert c.get("/api/v1/info", headers=wrong).status_code == 401
            assert c.get("/api/v1/info").status_code == 401  # no token: info lines, same limit
        assert len(caplog.records) == 3
        limit._times.clear()  # the window passed
        assert c.get("/api/v1/info", headers=wrong).status_code == 401
    assert len(caplog.records) == 4
    assert "97 similar lines left out" in caplog.records[-1].getMessage()
    assert "wrong token" in caplog.records[-1].getMessage()


def test_the_log_limit_admits_its_lines_per_window():
    limit = LogLimit(lines=2, window_s=60.0)
    assert [limit.allow() for _ in range(5)] == [0, 0, None, None, None]
    limit._times.clear()  # the window passed
    assert limit.allow() == 3


FULL = {"WOI_WIDTH": 2592, "WOI_HEIGHT": 1944, "WOI_LEFT": 0, "WOI_TOP": 0}


def test_the_largest_count_is_the_last_page_that_ends_within_4_gib():
    image = np.zeros((1944, 2592), dtype=np.uint16)
    metadata = {"pad": "x" * (tiff.DESCRIPTION_BOUND_BYTES - 20)}
    largest = tiff.largest_count(2592, 1944)
    offset = 8
    for _ in range(largest):
        _, offset = tiff.page_chunks(image, metadata, offset=offset, last=False)
    assert offset <= 2**32 - 1
    with pytest.raises(ValueError, match="4 GiB"):
        tiff.page_chunks(image, metadata, offset=offset, last=True)


@pytest.mark.parametrize("scheduled", [False, True])
def test_a_burst_past_4_gib_is_422_naming_the_largest_count_before_any_byte(
    camera, client, scheduled
):
    largest = tiff.largest_count(2592, 1944)
    assert 400 < largest < 489  # 489 full frames broke off at 4 GiB before this refusal
    if scheduled:  # a larger window scheduled ahead counts as well as the one in effect
        r = client.patch("/api/v1/ports/0/params?ahead=5", json=FULL, headers=AUTH)
    else:
        r = client.patch("/api/v1/ports/0/params", json=FULL, headers=AUTH)
    assert r.status_code == 200, r.text
    frame_before = camera.sequencer(0).this_frame
    r = client.post(f"/api/v1/ports/0/capture?count={largest + 1}", headers=AUTH)
    assert r.status_code == 422, r.text
    body = r.json()
    assert body["parameter"] == "count" and body["value"] == largest + 1
    assert f"1..{largest} frames of the window 2592x1944" in body["allowed"]
    assert camera.sequencer(0).this_frame == frame_before  # nothing was captured
    # The same count of small frames fits (asked for and refused by the schema's 1..1024
    # only): here 2 small frames are captured and end as a whole TIFF.
    r = client.patch("/api/v1/ports/0/params?ahead=6", json=SMALL, headers=AUTH)  # after FULL
    assert r.status_code == 200, r.text
    camera.board.sim_advance(frames=MAX_AHEAD + 2)
    r = client.post("/api/v1/ports/0/capture?count=2", headers=AUTH)
    assert r.status_code == 200
    with tifffile.TiffFile(io.BytesIO(r.content)) as tif:
        assert len(tif.pages) == 2 and tif.pages[0].shape == (48, 64)
