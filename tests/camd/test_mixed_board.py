"""The mixed board: a V4L2 port and a Lepton port in one daemon, from the config file."""

import io
import json
import re
import subprocess
import sys

import httpx
import numpy as np
import pytest
import tifffile
from fastapi.testclient import TestClient

from elphel_camd import cli
from elphel_camd.api import create_app
from elphel_camd.boards.mixed import MixedBoard
from elphel_camd.boards.v4l2 import V4L2Port
from elphel_camd.config import ConfigError, load_settings
from elphel_camd.service import CameraService
from elphel_camd.v4l2.synthetic import SyntheticSource
from elphel_camd.vospi import SpidevSource
from elphel_camd.vospi.record import record_stream
from elphel_sim.vospi import SimSpidev, SimVoSPIStream, digest

TOKEN = "t"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def camera_image() -> np.ndarray:
    return np.random.default_rng(5).integers(0, 1024, (16, 32), dtype=np.uint16)


class Node(SyntheticSource):
    closed = False

    def close(self) -> None:
        self.closed = True
        super().close()


def open_video(port: V4L2Port) -> Node:
    return Node(camera_image(), fourcc="pRAA", fps=50.0, path=port.video, pad=8)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """Twenty frames of the simulated Lepton (telemetry on), recorded, and its truth."""
    stream = SimVoSPIStream(seed=11)
    path = tmp_path_factory.mktemp("mixed") / "lepton.vospi"
    record_stream("sim", path, frames=20, source=SpidevSource(SimSpidev(stream), bufsiz=4096))
    return path, stream


def capture(client, port, **params):
    r = client.post(f"/api/v1/ports/{port}/capture", headers=AUTH, params=params)
    assert r.status_code == 200, r.text
    with tifffile.TiffFile(io.BytesIO(r.content)) as tif:
        return tif.pages[0].asarray(), json.loads(tif.pages[0].description)


def test_a_v4l2_port_and_a_lepton_port_serve_side_by_side(recording):
    path, stream = recording
    ports = [
        {"video": "/dev/video0", "model": "imx219", "timeout_periods": 7},
        {"vospi": str(path), "replay_fps": 40},
    ]
    board = MixedBoard(ports, open_video=open_video)
    assert board.boards[0].timeout_periods == 7
    service = CameraService(board)
    try:
        with TestClient(create_app(service, token=TOKEN, public_reads=True)) as c:
            info = c.get("/api/v1/info").json()
            assert info["board"] == "mixed" and info["capabilities"] == ["capture"]
            assert [p["port"] for p in info["ports"]] == [0, 1]
            assert info["ports"][1]["sensor"]["model"] == "LEPTON35"
            image, _ = capture(c, 0)
            np.testing.assert_array_equal(image, camera_image())
            thermal, thermal_meta = capture(c, 1)
            assert digest(thermal) == stream.truth[thermal_meta["frame"]].digest
            assert thermal_meta["telemetry"]["frame_counter"] == thermal_meta["frame"]
            health = c.get("/api/v1/health").json()
            streams = [p["stream"] for p in health["ports"]]
            assert [s["source"] for s in streams] == ["video", "vospi"]
            assert [s["state"] for s in streams] == ["streaming", "streaming"]
            r = c.patch(
                "/api/v1/ports/0/params", headers=AUTH, params={"ahead": 2}, json={"EXPOS": 2000}
            )
            assert r.status_code == 409 and "no frame syncs" in r.text
            assert c.post("/api/v1/ports/2/capture", headers=AUTH).status_code == 404
    finally:
        service.close()  # closes the board: its ports' threads end


@pytest.mark.parametrize(
    ("ports", "message"),
    [
        ([], 'the mixed board needs "ports" in the config file'),
        ([{"video": "/dev/video0"}, {"bus": "/dev/i2c-1"}], r"ports\[1\]: give one frame source"),
        ([{"video": "/dev/video0", "vospi": "/dev/spidev0.0"}], "got video and vospi"),
        ([{"video": "/dev/video0", "sensor": "imx219"}], r"ports\[0\] \(video\): sensor: Extra"),
        ([{"vospi": "x", "spi_clock_hz": 40_000_000}], r"ports\[0\] \(vospi\): spi_clock_hz: "),
        ([{"vospi": "x", "telemetry_location": "side"}], "telemetry_location: Input should be"),
        ([{"video": "/dev/video0", "buffers": 1}], r"ports\[0\] \(video\): buffers: Input should"),
        (["/dev/video0"], r"ports\[0\]: a JSON object is needed, not str"),
    ],
)
def test_a_bad_port_entry_is_refused_before_any_device_is_opened(ports, message):
    opened = []
    with pytest.raises(ConfigError, match=message):
        MixedBoard(ports, open_video=lambda port: opened.append(port) or open_video(port))
    assert opened == []


def test_the_daemon_takes_the_board_and_its_ports_from_the_config_file(tmp_path, capsys):
    cfg = tmp_path / "config.json"
    ports = [{"video": "/dev/video0"}, {"vospi": "/dev/spidev7.7", "bus": 3}]
    cfg.write_text(json.dumps({"board": "mixed", "ports": ports}))
    assert load_settings(cfg).board_options == {"ports": ports}
    assert cli.main(["--config", str(cfg), "--state-dir", str(tmp_path), "--port", "0"]) == 1
    err = capsys.readouterr().err.strip()
    assert err == "elphel-camd: board mixed: ports[1] (vospi): bus: Input should be a valid string"


def test_the_daemon_without_a_board_says_where_to_name_one(tmp_path, capsys):
    cfg = tmp_path / "config.json"
    cfg.write_text(json.dumps({"host": "127.0.0.1"}))
    assert cli.main(["--config", str(cfg), "--state-dir", str(tmp_path)]) == 1
    assert capsys.readouterr().err.strip() == (
        'elphel-camd: no board: give --board or "board" in the config file'
    )


def test_a_port_that_cannot_open_closes_the_ports_opened_before(tmp_path):
    made = []

    def video(port):
        made.append(open_video(port))
        return made[-1]

    ports = [{"video": "/dev/video0"}, {"vospi": str(tmp_path / "missing")}]
    with pytest.raises(Exception, match="missing: cannot open the Lepton's VoSPI"):
        MixedBoard(ports, open_video=video)
    assert len(made) == 1 and made[0].closed


def test_the_daemon_serves_the_ports_of_its_config_file(recording, tmp_path):
    """elphel-camd --config FILE as a process: the mixed board of two Lepton recordings."""
    path, stream = recording
    config = tmp_path / "config.json"
    ports = [{"vospi": str(path), "replay_fps": 2}, {"vospi": str(path), "replay_fps": 2}]
    config.write_text(json.dumps({"board": "mixed", "ports": ports, "token": TOKEN}))
    args = ["--config", str(config), "--port", "0", "--state-dir", str(tmp_path)]
    proc = subprocess.Popen(
        [sys.executable, "-m", "elphel_camd.cli", *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stderr is not None
    try:
        url = None
        for line in proc.stderr:
            found = re.search(r"listening on (http://[\d.]+:\d+)", line)
            if found:
                url = found.group(1)
                break
        assert url is not None, "the daemon did not start"
        with httpx.Client(base_url=url, headers=AUTH, timeout=10) as http:
            assert http.get("/api/v1/info").json()["board"] == "mixed"
            for port in (0, 1):
                r = http.post(f"/api/v1/ports/{port}/capture")
                assert r.status_code == 200, r.text
                with tifffile.TiffFile(io.BytesIO(r.content)) as tif:
                    meta = json.loads(tif.pages[0].description)
                    assert digest(tif.pages[0].asarray()) == stream.truth[meta["frame"]].digest
                assert meta["port"] == port
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        proc.stderr.close()
