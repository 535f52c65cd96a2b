"""Secure defaults of elphel-camd: the token on reads, rotation, back-off, limits, TLS.

Each test states one promise of docs/security.md and fails if the daemon breaks it.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import shutil
import signal
import socket
import ssl
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient

from elphel_camd import cli
from elphel_camd.api import create_app
from elphel_camd.api.deps import FailedAuth, TokenSource
from elphel_camd.service import CameraService
from elphel_camd.store import ParamStore
from elphel_sim.board import SimCameraBoard
from elphel_sim.scenarios import build

TOKEN = "sec-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
SMALL = {"WOI_WIDTH": 64, "WOI_HEIGHT": 48, "WOI_LEFT": 1200, "WOI_TOP": 900}
READS = [
    "/api/v1/info",
    "/api/v1/ports/0/params",
    "/api/v1/ports/0/frame",
    "/api/v1/ports/0/registers",
    "/api/v1/ports/0/registers/0x00",
    "/api/v1/events?count=1",
]


@pytest.fixture
def camera(tmp_path):
    board = SimCameraBoard(build("default", seed=3), seed=3, noise=False)
    cam = CameraService(board, store=ParamStore(tmp_path / "params"))
    cam.set_params(0, SMALL)
    board.sim_advance(frames=4)
    yield cam
    cam.close()


def test_reads_need_the_token_by_default_and_the_schema_says_so(camera):
    with TestClient(create_app(camera, token=TOKEN)) as c:
        for url in READS:
            r = c.get(url)
            assert r.status_code == 401, url
            assert r.headers["www-authenticate"] == "Bearer"
            assert r.json()["error"] == "unauthorized"
        for url in READS[:-1]:
            assert c.get(url, headers=AUTH).status_code == 200, url
        assert c.get("/api/v1/health").status_code == 200  # monitors need no token
        paths = c.get("/openapi.json").json()["paths"]
    for path, item in paths.items():
        for method, op in item.items():
            # /health for monitors; / is the browser page, which asks for the token itself
            needs = path not in ("/api/v1/health", "/")
            assert ("security" in op) is needs, (method, path)
            assert ("401" in op["responses"]) is needs, (method, path)


def test_public_reads_open_the_reads_only_and_the_schema_says_so(camera):
    with TestClient(create_app(camera, token=TOKEN, public_reads=True)) as c:
        for url in READS[:-1]:
            assert c.get(url).status_code == 200, url
        r = c.patch("/api/v1/ports/0/params", json={"EXPOS": 1000})
        assert r.status_code == 401
        paths = c.get("/openapi.json").json()["paths"]
    for path, item in paths.items():
        for method, op in item.items():
            assert ("security" in op) is (method != "get"), (method, path)


def test_token_rotate_replaces_the_file_and_the_old_token_is_refused_at_once(
    camera, tmp_path, capsys
):
    path = tmp_path / "state" / "token"
    path.parent.mkdir()
    path.write_text("old-token\n")
    path.chmod(0o600)
    app = create_app(camera, token=TokenSource(path=path))
    old = {"Authorization": "Bearer old-token"}
    with TestClient(app) as c:
        assert c.get("/api/v1/info", headers=old).status_code == 200
        assert cli.main(["token", "rotate", "--token-file", str(path)]) == 0
        new = capsys.readouterr().out.strip()
        assert new and new != "old-token" and path.read_text().strip() == new
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
        assert c.get("/api/v1/info", headers=old).status_code == 401
        assert c.get("/api/v1/info", headers={"Authorization": f"Bearer {new}"}).status_code == 200


def test_failed_tokens_are_logged_with_the_peer_and_slowed_down_boundedly(camera, caplog):
    app = create_app(camera, token=TOKEN)
    app.state.options.failed = FailedAuth(base_s=0.05, max_s=0.2)
    wrong = {"Authorization": "Bearer sec-tokem"}  # one character off: no faster, no hint
    with TestClient(app) as c, caplog.at_level(logging.WARNING, "elphel_camd.auth"):
        times = []
        for _ in range(5):
            t0 = time.monotonic()
            r = c.get("/api/v1/info", headers=wrong)
            times.append(time.monotonic() - t0)
            assert r.status_code == 401
            assert r.json()["detail"] == (
                "this request needs the camera's token: send Authorization: Bearer <token>"
            )
        # 0.05, 0.1, 0.2, then the bound 0.2
        assert times[0] >= 0.05 and times[1] >= 0.1 and times[2] >= 0.2
        assert max(times) < 0.2 + 0.5
        assert "testclient" in caplog.text and "wrong token" in caplog.text
        assert "failure 5" in caplog.text
        # A success forgets the peer's failures.
        assert c.get("/api/v1/info", headers=AUTH).status_code == 200
        t0 = time.monotonic()
        c.get("/api/v1/info", headers=wrong)
        assert time.monotonic() - t0 < 0.2


def test_back_off_is_per_peer_and_remembers_a_bounded_number_of_peers():
    failed = FailedAuth(base_s=0.1, max_s=1.0, peers=3)
    assert [failed.fail("a")[1] for _ in range(5)] == [0.1, 0.2, 0.4, 0.8, 1.0]
    assert failed.fail("b") == (1, 0.1)
    for peer in ("c", "d"):
        failed.fail(peer)
    assert failed.failures("a") == 0  # the least recent forgotten, "b" kept
    assert failed.failures("b") == 1


def test_a_chunked_body_over_the_limit_is_413_naming_the_limit(camera):
    with TestClient(create_app(camera, token=TOKEN)) as c:

        def chunks():
            for _ in range(17):
                yield b" " * 4096  # 68 KiB, no Content-Length

        r = c.patch(
            "/api/v1/ports/0/params",
            content=chunks(),
            headers={**AUTH, "content-type": "application/json"},
        )
        assert r.status_code == 413, r.text
        assert r.json()["limit"] == "max_body_bytes" and r.json()["maximum"] == 65536

        def small():
            yield b'{"EXPOS": '
            yield b"2000}"

        r = c.patch(
            "/api/v1/ports/0/params",
            content=small(),
            headers={**AUTH, "content-type": "application/json"},
        )
        assert r.status_code == 200, r.text


def test_the_host_header_must_name_the_camera(camera):
    app = create_app(camera, token=TOKEN, allowed_hosts=["cam1.lab"])
    with TestClient(app, base_url="http://evil.example") as c:
        r = c.get("/api/v1/health")
        assert r.status_code == 421 and r.json()["error"] == "host_not_allowed"
        assert "evil.example" in r.json()["detail"]
        for host in ("cam1.lab", "cam1.lab:8000", "192.168.0.9:8000", "[::1]:8000", "localhost"):
            assert c.get("/api/v1/health", headers={"host": host}).status_code == 200, host


def test_cors_is_off_unless_origins_are_listed(camera):
    origin = {"Origin": "http://lab.example"}
    with TestClient(create_app(camera, token=TOKEN)) as c:
        r = c.get("/api/v1/health", headers=origin)
        assert "access-control-allow-origin" not in r.headers
    with TestClient(create_app(camera, token=TOKEN, cors_origins=["http://lab.example"])) as c:
        r = c.get("/api/v1/health", headers=origin)
        assert r.headers["access-control-allow-origin"] == "http://lab.example"
        r = c.get("/api/v1/health", headers={"Origin": "http://evil.example"})
        assert "access-control-allow-origin" not in r.headers


@pytest.mark.parametrize("number", ["NaN", "Infinity", "-Infinity", "1e400"])
def test_non_finite_numbers_are_422_json_not_500(camera, number):
    with TestClient(create_app(camera, token=TOKEN), raise_server_exceptions=False) as c:
        before = c.get("/api/v1/ports/0/params", headers=AUTH).json()
        json_headers = {**AUTH, "content-type": "application/json"}
        r = c.patch(
            "/api/v1/ports/0/params", content=f'{{"EXPOS": {number}}}', headers=json_headers
        )
        assert r.status_code == 422, r.text
        body = r.json()
        assert body["parameter"] == "EXPOS" and "finite" in body["allowed"]
        assert body["value"] in ("NaN", "Infinity", "-Infinity")
        r = c.put(
            "/api/v1/ports/0/registers/0x35", content=f'{{"value": {number}}}', headers=json_headers
        )
        assert r.status_code == 422 and r.json()["parameter"] == "value", r.text
        camera.board.sim_advance(frames=4)
        assert c.get("/api/v1/ports/0/params", headers=AUTH).json()["EXPOS"] == before["EXPOS"]


def test_params_of_a_frame_past_the_schedule_are_refused(camera):
    with TestClient(create_app(camera, token=TOKEN)) as c:
        now = c.get("/api/v1/ports/0/frame", headers=AUTH).json()["frame"]
        assert c.get(f"/api/v1/ports/0/params?frame={now + 14}", headers=AUTH).status_code == 200
        r = c.get(f"/api/v1/ports/0/params?frame={now + 100000}", headers=AUTH)
        assert r.status_code == 404 and r.json()["error"] == "frame_not_available"
        assert "beyond the schedule" in r.json()["detail"]


def test_405_allow_lists_every_method_of_the_path(camera):
    with TestClient(create_app(camera, token=TOKEN)) as c:
        for path, methods in (
            ("/api/v1/ports/0/params", {"GET", "PATCH"}),
            ("/api/v1/ports/0/registers/0x00", {"GET", "PUT"}),
            ("/api/v1/ports/0/capture", {"POST"}),
        ):
            r = c.options(path, headers=AUTH)
            assert r.status_code == 405
            allow = {m.strip() for m in r.headers["allow"].split(",")} - {"HEAD"}
            assert allow == methods, (path, r.headers["allow"])


def test_the_docs_page_needs_nothing_from_the_network(camera):
    with TestClient(create_app(camera, token=TOKEN)) as c:
        page = c.get("/docs")
        assert page.status_code == 200 and "/openapi.json" in page.text
        assert "http://" not in page.text and "https://" not in page.text
        assert "/api/v1/ports/{port}/params" in page.text


def test_unwritable_state_dir_refuses_writes_with_503_and_keeps_the_last_settings(
    camera, monkeypatch
):
    store = camera.store
    journal = store.journal_path(0)
    with TestClient(create_app(camera, token=TOKEN)) as c:
        assert (
            c.patch("/api/v1/ports/0/params", json={"EXPOS": 3000}, headers=AUTH).status_code == 200
        )
        camera.board.sim_advance(frames=4)
        before = c.get("/api/v1/ports/0/params", headers=AUTH).json()
        saved = journal.read_bytes()
        real_write = os.write

        def full(fd, data):
            if fd in store._journals.values():
                raise OSError(errno.ENOSPC, "No space left on device")
            return real_write(fd, data)

        monkeypatch.setattr("elphel_camd.store.os.write", full)
        r = c.patch("/api/v1/ports/0/params", json={"EXPOS": 9000, "FLIPH": 1}, headers=AUTH)
        assert r.status_code == 503, r.text
        body = r.json()
        assert body["error"] == "state_not_writable"
        assert "No space left" in body["detail"] and str(journal) in body["detail"]
        camera.board.sim_advance(frames=16)
        now = c.get("/api/v1/ports/0/params", headers=AUTH).json()  # reads keep working
        assert (now["EXPOS"], now["FLIPH"]) == (before["EXPOS"], before["FLIPH"])
        assert journal.read_bytes() == saved
        monkeypatch.setattr("elphel_camd.store.os.write", real_write)
        assert (
            c.patch("/api/v1/ports/0/params", json={"EXPOS": 9000}, headers=AUTH).status_code == 200
        )


def test_journal_stays_near_its_bound_under_steady_writes(tmp_path):
    store = ParamStore(tmp_path)
    store.flush_interval_s = 0.01
    params = {f"P{i}": i * 1000 for i in range(40)}  # ~600-byte lines
    biggest = 0
    deadline = time.monotonic() + 3.0
    n = 0
    try:
        while time.monotonic() < deadline:
            n += 1
            store.save(0, "MT9P006", {**params, "EXPOS": n})
            if n % 20 == 0:
                biggest = max(biggest, store.journal_path(0).stat().st_size)
    finally:
        store.close()
    assert n > 1000  # steady writes: never a pause for the flusher to wait for
    assert biggest <= 2 * store.compact_bytes, biggest
    assert store.load(0, "MT9P006")["EXPOS"] == n
    with ParamStore(tmp_path) as fresh:
        assert fresh.load(0, "MT9P006")["EXPOS"] == n


def test_concurrent_patches_answer_the_frame_of_their_own_values(camera):
    errors: list[str] = []
    with TestClient(create_app(camera, token=TOKEN)) as c:
        stop = threading.Event()

        def clock():
            while not stop.is_set():
                camera.board.sim_advance(frames=1)
                time.sleep(0.001)

        def writer(k: int) -> None:
            for i in range(30):
                left = 2 * (100 * k + i)
                r = c.patch("/api/v1/ports/0/params", json={"WOI_LEFT": left}, headers=AUTH)
                if r.status_code != 200:
                    errors.append(r.text)
                elif r.json()["params"]["WOI_LEFT"] != left:
                    errors.append(f"answered frame {r.json()['frame']} without its own value")

        ticker = threading.Thread(target=clock)
        ticker.start()
        threads = [threading.Thread(target=writer, args=(k,)) for k in range(6)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        stop.set()
        ticker.join()
    assert not errors, errors[:3]


# -- TLS --------------------------------------------------------------------------------------


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.skipif(shutil.which("openssl") is None, reason="makes the certificate with openssl")
def test_tls_round_trip_with_a_self_signed_certificate(tmp_path):
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    names = "subjectAltName=DNS:localhost,IP:127.0.0.1"
    subprocess.run(
        [
            *("openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1"),
            *("-subj", "/CN=localhost", "-addext", names),
            *("-keyout", str(key), "-out", str(cert)),
        ],
        check=True,
        capture_output=True,
    )
    port = _free_port()
    config = tmp_path / "config.json"
    config.write_text(json.dumps({"state_dir": str(tmp_path / "state"), "access_log": False}))
    log = tmp_path / "daemon.log"
    command = [sys.executable, "-m", "elphel_camd.cli", "--board", "sim", "--config", str(config)]
    command += ["--port", str(port), "--tls-cert", str(cert), "--tls-key", str(key)]
    env = {**os.environ, "ELPHEL_CAMD_TOKEN": TOKEN}
    with log.open("w") as err:
        proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=err, env=env)
    try:
        deadline = time.monotonic() + 60
        while "listening on https://" not in log.read_text():
            assert proc.poll() is None, log.read_text()
            assert time.monotonic() < deadline, log.read_text()
            time.sleep(0.05)
        context = ssl.create_default_context(cafile=str(cert))
        with httpx.Client(base_url=f"https://127.0.0.1:{port}", verify=context) as client:
            assert client.get("/api/v1/health").status_code == 200
            assert client.get("/api/v1/info").status_code == 401
            info = client.get("/api/v1/info", headers=AUTH)
            assert info.status_code == 200 and info.json()["board"] == "sim"
        with pytest.raises(httpx.HTTPError):  # plain http is not answered as http
            httpx.get(f"http://127.0.0.1:{port}/api/v1/health", timeout=5)
        with pytest.raises(httpx.ConnectError):  # an unknown certificate is refused
            httpx.get(f"https://127.0.0.1:{port}/api/v1/health", timeout=5)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()


def test_tls_needs_both_the_certificate_and_the_key(tmp_path, capsys):
    code = cli.main(
        ["--board", "sim", "--state-dir", str(tmp_path), "--tls-cert", str(tmp_path / "c.pem")]
    )
    assert code == 1
    assert "--tls-cert and --tls-key" in capsys.readouterr().err


def test_token_rotate_writes_a_new_file_0600(tmp_path, capsys):
    path = tmp_path / "token"
    assert cli.main(["token", "rotate", "--token-file", str(path)]) == 0
    first = capsys.readouterr().out.strip()
    assert path.read_text().strip() == first and stat.S_IMODE(path.stat().st_mode) == 0o600
    assert cli.main(["token", "rotate", "--token-file", str(path), "--quiet"]) == 0
    assert capsys.readouterr().out == ""
    assert path.read_text().strip() not in ("", first)
    assert not list(Path(tmp_path).glob(".*.tmp"))


# -- I2C fault in the middle of a multi-parameter PATCH ----------------------------------------


class ImmediateBoard:
    """The simulated chips on a board without frame syncs: a PATCH writes them at once."""

    name = "immediate"
    capabilities = frozenset()

    def __init__(self, sim: SimCameraBoard) -> None:
        self.sim = sim

    def buses(self):
        return self.sim.buses()

    def on_frame_sync(self, callback) -> None:
        pass

    def program(self, port, function, state) -> None:
        pass

    def capture(self, port, *, frame=None):
        raise AssertionError("not used")

    def close(self) -> None:
        self.sim.close()


def test_i2c_fault_mid_patch_changes_nothing_and_names_port_address_register():
    sim = SimCameraBoard(build("default", seed=4), seed=4, noise=False)
    camera = CameraService(ImmediateBoard(sim))
    chip = sim.chips[0]
    bus = sim.bus(0)
    try:
        with TestClient(create_app(camera, token=TOKEN)) as c:
            before = c.get("/api/v1/ports/0/params", headers=AUTH).json()
            registers = dict(chip.values)
            real = bus.i2c_rdwr
            calls = {"n": 0}

            def flaky(*msgs):
                calls["n"] += 1
                if calls["n"] == 4:  # some registers written already
                    bus.sim_nak(2)  # both attempts of one transfer
                return real(*msgs)

            bus.i2c_rdwr = flaky
            change = {**SMALL, "EXPOS": 2000, "GAINR": 0x20000, "FLIPH": 1}
            r = c.patch("/api/v1/ports/0/params", json=change, headers=AUTH)
            bus.i2c_rdwr = real
            assert r.status_code == 503, r.text
            body = r.json()
            assert body["error"] == "i2c" and body["port"] == 0 and body["address"] == 0x48
            assert isinstance(body["register"], int)
            assert "port 0" in body["detail"] and "0x48" in body["detail"]
            assert "nothing was changed" in body["detail"]
            assert c.get("/api/v1/ports/0/params", headers=AUTH).json() == before
            assert dict(chip.values) == registers
            # The bus works again: the same change goes through whole.
            r = c.patch("/api/v1/ports/0/params", json=change, headers=AUTH)
            assert r.status_code == 200 and r.json()["params"]["FLIPH"] == 1
    finally:
        camera.close()


def test_an_i2c_failure_a_request_meets_is_answered_503_and_logged_once(camera, caplog):
    with TestClient(create_app(camera, token=TOKEN)) as c:
        with caplog.at_level(logging.DEBUG, "elphel_camd"):
            camera.board.bus(0).sim_nak(2)  # both attempts of the one transfer
            r = c.get("/api/v1/ports/0/registers/0x00", headers=AUTH)
        assert r.status_code == 503, r.text
        assert r.json()["error"] == "i2c"
    warnings = [rec.getMessage() for rec in caplog.records if rec.levelno >= logging.WARNING]
    assert len(warnings) == 1, warnings
    assert warnings[0].startswith("GET /api/v1/ports/0/registers/0x00: port 0: device 0x48")
