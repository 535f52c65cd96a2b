"""The lepton board in the daemon: VoSPI frames with telemetry, the CCI, a stopped device."""

import contextlib
import io
import json
import re
import subprocess
import sys
import time

import httpx
import numpy as np
import pytest
import tifffile
from fastapi.testclient import TestClient

from elphel_camd import cli
from elphel_camd.api import create_app
from elphel_camd.boards.lepton import LeptonBoard
from elphel_camd.service import CameraService
from elphel_camd.vospi import SpidevSource
from elphel_camd.vospi import telemetry as tm
from elphel_camd.vospi.frame_source import LeptonFrameSource
from elphel_camd.vospi.record import record_stream
from elphel_sim.board import SimCameraBoard
from elphel_sim.chips.bus import SimI2CBus
from elphel_sim.chips.lepton35 import SimLepton35
from elphel_sim.scenarios import build
from elphel_sim.vospi import SimSpidev, SimVoSPIStream, digest

LEPTON_PORT = 2  # in the simulator's mixed scenario
TOKEN = "t"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """Twenty frames of the simulated Lepton (telemetry on), recorded, and its truth."""
    stream = SimVoSPIStream(seed=3)
    path = tmp_path_factory.mktemp("lepton") / "lepton.vospi"
    source = SpidevSource(SimSpidev(stream), bufsiz=4096)
    summary = record_stream("sim", path, frames=20, source=source)
    assert summary["frames"] == 20 and summary["bytes"] == path.stat().st_size
    return path, stream


@contextlib.contextmanager
def client_of(board):
    """A client of a daemon on ``board``; the daemon's service is closed at the end."""
    service = CameraService(board)
    try:
        with TestClient(create_app(service, token=TOKEN, public_reads=True)) as client:
            yield client
    finally:
        service.close()


def capture(client, **params):
    r = client.post("/api/v1/ports/0/capture", headers=AUTH, params=params)
    assert r.status_code == 200, r.text
    with tifffile.TiffFile(io.BytesIO(r.content)) as tif:
        return tif.pages[0].asarray(), json.loads(tif.pages[0].description), r


def test_a_recording_replays_with_telemetry_in_each_frames_metadata(recording):
    path, stream = recording
    board = LeptonBoard(str(path), replay_fps=40)
    with client_of(board) as c:
        info = c.get("/api/v1/info").json()
        assert info["board"] == "lepton"
        assert info["ports"][0]["sensor"]["model"] == "LEPTON35"
        assert info["ports"][0]["sensor"]["cci"] is False
        image, meta, r = capture(c)
        assert image.shape == (120, 160) and image.dtype == np.uint16
        n = meta["frame"]
        assert r.headers["X-Frame-Number"] == str(n) == str(meta["telemetry"]["frame_counter"])
        assert digest(image) == stream.truth[n].digest
        assert meta["pixel_unit"] == "centikelvin"
        assert meta["telemetry"]["fpa_temperature_centi_k"] == 30515
        assert meta["telemetry"]["ffc_state"] == "done"
        assert c.get("/api/v1/health").json()["ports"][0]["stream"]["state"] == "streaming"
        capture(c)  # a later frame; the first one is then fetched by its number
        again, meta_again, _ = capture(c, frame=n)
        assert meta_again["frame"] == n and np.array_equal(again, image)


def test_without_the_cci_settings_are_refused_naming_the_bus_option(recording):
    with client_of(LeptonBoard(str(recording[0]), replay_fps=40)) as c:
        r = c.patch("/api/v1/ports/0/params", headers=AUTH, json={"WOI_HEIGHT": 122})
        assert r.status_code == 409
        assert "--bus /dev/i2c-N" in r.json()["detail"]


def test_with_the_cci_the_pixel_unit_comes_from_the_camera(recording):
    bus = SimI2CBus("lepton CCI")
    chip = SimLepton35()
    bus.attach(chip.address, chip)
    chip.attributes["RAD_TLINEAR_RESOLUTION"] = 0  # 0.1 K a count
    stream = SimVoSPIStream(lambda n: np.zeros((120, 160), np.uint16) + n)
    board = LeptonBoard("sim", byte_source=SpidevSource(SimSpidev(stream), bufsiz=4096), bus=bus)
    assert board.pixel_unit == "decikelvin"
    service = CameraService(board)
    try:
        assert service.sensor(0).model == "LEPTON35" and service.sensor(0).writable
        frame, meta = service.capture(0)
        assert meta["pixel_unit"] == "decikelvin" and "telemetry" not in meta
        assert np.all(frame.image == frame.image[0, 0])
    finally:
        service.close()


def test_a_lepton_that_stops_sending_is_504_and_the_port_says_so():
    stream = SimVoSPIStream()
    spidev = SimSpidev(stream, time_scale=1.0)
    board = LeptonBoard("/dev/spidev0.0", byte_source=SpidevSource(spidev, bufsiz=4096))
    board.capture_timeout_s = 2.0
    with client_of(board) as c:
        capture(c)
        stream.sim_stall(stream.t, 1e9)  # from now on: discard packets only
        deadline = time.monotonic() + 30
        while board.port_status(0)["state"] != "stalled":
            assert time.monotonic() < deadline, "the stream was never reported stalled"
            time.sleep(0.1)
        board.capture_timeout_s = 0.5
        r = c.post("/api/v1/ports/0/capture", headers=AUTH)
        assert r.status_code == 504
        assert "/dev/spidev0.0: no frame from the Lepton" in r.json()["detail"]
        r = c.get("/api/v1/health")
        assert r.status_code == 503
        health = r.json()
        assert health["status"] == "degraded"
        port = health["ports"][0]
        assert port["ok"] is False and port["error"] == "stalled"
        assert port["detail"].startswith("/dev/spidev0.0: no frame for")
        assert port["stream"]["state"] == "stalled"
        assert port["stream"]["resyncs"] >= 1


def test_the_daemon_names_a_missing_vospi_device(capsys):
    assert cli.main(["--board", "lepton", "--vospi", "/dev/spidev7.7", "--port", "0"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("elphel-camd: board lepton: /dev/spidev7.7: cannot open")
    assert "\n" not in err


def test_vospi_record_names_a_missing_device(capsys, tmp_path):
    out = tmp_path / "x.vospi"
    assert cli.main(["vospi-record", "/dev/spidev7.7", "--out", str(out), "--frames", "3"]) == 1
    assert "/dev/spidev7.7: cannot open the Lepton's" in capsys.readouterr().err


def test_the_daemon_serves_a_recording_given_with_vospi(recording, tmp_path):
    """elphel-camd --board lepton --vospi FILE, as a process, answered over HTTP."""
    path, stream = recording
    config = tmp_path / "config.json"
    config.write_text(json.dumps({"replay_fps": 2}))  # 10 s: time to start
    args = ["--board", "lepton", "--vospi", str(path), "--port", "0", "--token", TOKEN]
    args += ["--state-dir", str(tmp_path), "--config", str(config)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "elphel_camd.cli", *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        url = None
        for line in proc.stderr:
            found = re.search(r"listening on (http://[\d.]+:\d+)", line)
            if found:
                url = found.group(1)
                break
        assert url is not None, "the daemon did not start"
        with httpx.Client(base_url=url, headers=AUTH, timeout=10) as http:
            r = http.post("/api/v1/ports/0/capture")
            assert r.status_code == 200, r.text
            with tifffile.TiffFile(io.BytesIO(r.content)) as tif:
                image = tif.pages[0].asarray()
                meta = json.loads(tif.pages[0].description)
        assert digest(image) == stream.truth[meta["frame"]].digest
        assert meta["telemetry"]["frame_counter"] == meta["frame"]
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        proc.stderr.close()


def test_the_simulated_chips_telemetry_rows_decode_as_a_lepton_s():
    board = SimCameraBoard(build("mixed", seed=1), seed=1, noise=False)
    service = CameraService(board)
    try:
        target = service.set_params(LEPTON_PORT, {"WOI_HEIGHT": 122})
        frame, _ = service.capture(LEPTON_PORT, frame=target)
        t = tm.decode(frame.image[120:])
        assert (t.frame_counter, t.ffc_state, t.tlinear) == (target, "never", True)
        assert t.tlinear_resolution_k == 0.01 and t.fpa_temperature_centi_k == 30515
        service.sensor(LEPTON_PORT).run_ffc()
        frame, _ = service.capture(LEPTON_PORT)
        assert tm.decode(frame.image[120:]).ffc_state == "done"
    finally:
        service.close()


def test_vospi_record_writes_a_recording_that_replays(recording, tmp_path, capsys):
    out = tmp_path / "again.vospi"
    args = ["vospi-record", str(recording[0]), "--out", str(out), "--frames", "5", "--json"]
    assert cli.main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frames"] == 5 and summary["bytes"] == out.stat().st_size > 0
    source = LeptonFrameSource(str(out), replay_fps=0)
    source.open()
    try:
        assert source.read_frame(after=0, timeout_s=5).number == 1
    finally:
        source.close()
