"""`elphel tp capture` then `elphel tp`: from a simulated quad camera to a DSI in two commands.

The quad scenario (`elphel-sim up --scenario quad`) is four MT9P006 on Elphel's square
seeing planes at known disparities; the simulator's ``/quad/truth`` gives the true
disparity of every tile.
"""

import json
import re
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import tifffile
import uvicorn

from elphel_camd.api import create_app
from elphel_camd.service import CameraService
from elphel_host.camera import CameraClient
from elphel_host.tp.dsi import read_dsi
from elphel_sim.board import SimCameraBoard
from elphel_sim.launcher import bind_loopback
from elphel_sim.scenarios import build

from .rig import run_cli, running_rig

TRIGGER = ("TRIG", "TRIG_PERIOD", "TRIG_MASTER", "TRIG_DELAY", "TRIG_DECIMATE")


@pytest.fixture(scope="module")
def quad_rig() -> Iterator[dict[str, Any]]:
    with running_rig("--scenario", "quad", "--seed", "0") as announce:
        yield announce


def test_capture_then_tp_recovers_the_scene_disparities(quad_rig, tmp_path):
    cam_url, token, sim_url = quad_rig["camera_url"], quad_rig["token"], quad_rig["sim_url"]
    geometry = httpx.get(f"{sim_url}/quad").json()
    (tmp_path / "geometry.json").write_text(json.dumps(geometry))
    with CameraClient(cam_url, token) as cam:
        before = {p: {k: cam.params(p)[k] for k in TRIGGER} for p in range(4)}
    quad, dsi = tmp_path / "quad", tmp_path / "dsi.tif"

    # command 1: one trigger-synchronised set
    r = run_cli(
        "tp", "capture", "--camera", cam_url, "--token", token, "--out", str(quad),
        "--geometry", str(tmp_path / "geometry.json"), "--json",
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert len(r.stdout.splitlines()) == 1
    result = json.loads(r.stdout)
    # progress on stderr, a plain line per step (not a terminal: no bar, no \r), after
    # one line saying the trigger period chosen from a timed fetch
    said, *steps = [line for line in r.stderr.splitlines() if line.startswith("tp capture: ")]
    assert re.fullmatch(
        r"tp capture: one frame took .* s to fetch: .*; trigger period \d+ ms", said
    )
    assert [s.split()[2] for s in steps] == [f"{i}/8" for i in range(1, 9)], r.stderr
    assert sum("fetched" in s for s in steps) == 4 and "written" in steps[-1]
    assert "left)" in steps[-2] and "\r" not in r.stderr and "━" not in r.stderr
    manifest = json.loads((quad / "quad.json").read_text())
    cams = manifest["cameras"]
    assert [c["port"] for c in cams] == [0, 1, 2, 3]
    assert [c["position"] for c in cams] == [[-0.5, -0.5], [0.5, -0.5], [-0.5, 0.5], [0.5, 0.5]]
    assert {c["timestamp_ns"] for c in cams} == {result["timestamp_ns"]}
    assert all(c["params"]["TRIG"] == 4 and c["params"]["TRIG_MASTER"] == 0 for c in cams)
    assert manifest["bayer"] == "GRBG" and manifest["full_scale_dn"] == 4095
    assert manifest["optics"]["baseline_mm"] == 150.0
    assert manifest["capture"]["timestamp_ns"] == result["timestamp_ns"]
    for c in cams:
        image = tifffile.imread(quad / c["file"])
        assert image.dtype == np.uint16 and image.shape == (1944, 2592)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["geometry.json", "quad"]

    # command 2: the DSI
    r = run_cli("tp", str(quad), "--out", str(dsi), "--json")
    assert r.returncode == 0, r.stderr
    measured = read_dsi(dsi)[0]["disparity"]
    truth = httpx.get(f"{sim_url}/quad/truth", timeout=60).json()
    disparity = np.array(truth["disparity"])
    label = np.array(truth["label"])
    good = np.array(truth["interior"]) & np.array(truth["textured"])
    error = measured - disparity
    fronto_ids = [i for i, n in enumerate(truth["names"]) if n.startswith("fronto")]
    fronto = good & np.isin(label, fronto_ids)
    assert good.sum() > 60_000
    # Measured on three captures (seed 0): 0.0284-0.0285 px on all well-textured tiles,
    # 0.0258-0.0261 px on the fronto-parallel ones, medians within 0.002 px per plane.
    assert np.sqrt(np.mean(error[good] ** 2)) < 0.033
    assert np.sqrt(np.mean(error[fronto] ** 2)) < 0.029
    for i in fronto_ids:
        assert abs(np.median(error[good & (label == i)])) < 0.01, truth["names"][i]

    # the camera's trigger settings are back
    with CameraClient(cam_url, token) as cam:
        after = {p: {k: cam.params(p)[k] for k in TRIGGER} for p in range(4)}
    assert after == before


def test_fewer_than_four_sensor_ports_is_a_clear_error(sim_rig, tmp_path):
    quad = tmp_path / "quad"
    r = run_cli(
        "tp", "capture", "--camera", sim_rig["camera_url"], "--token", sim_rig["token"],
        "--out", str(quad),
    )  # fmt: skip
    assert r.returncode == 1 and r.stdout == ""
    assert len(r.stderr.strip().splitlines()) == 1
    assert "ports 0 (1 of 4), none on 1, 2, 3" in r.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_non_empty_quad_dir_is_kept_without_force(tmp_path):
    quad = tmp_path / "quad"
    quad.mkdir()
    (quad / "notes.txt").write_text("mine")
    r = run_cli("tp", "capture", "--camera", "http://127.0.0.1:9", "--out", str(quad))
    assert r.returncode == 1
    assert "is not empty; give --force" in r.stderr
    assert (quad / "notes.txt").read_text() == "mine"


@pytest.fixture
def skewed_quad() -> Iterator[tuple[str, SimCameraBoard]]:
    """The quad scenario served in this process, so a test can reach the board's hooks."""
    board = SimCameraBoard(build("quad", seed=2), seed=2)
    camera = CameraService(board)
    board.start_clock()
    sock = bind_loopback(0)
    app = create_app(camera, token="tok")
    # off the main thread uvicorn leaves signal handling alone
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", lifespan="off"))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    host, port = sock.getsockname()[:2]
    try:
        yield f"http://{host}:{port}", board
    finally:
        server.should_exit = True
        thread.join(timeout=10)
        camera.close()
        sock.close()


def test_frames_of_different_timestamps_are_refused_and_nothing_is_written(
    skewed_quad, tmp_path: Path
):
    url, board = skewed_quad
    small = {"WOI_WIDTH": 256, "WOI_HEIGHT": 192, "WOI_LEFT": 1168, "WOI_TOP": 876}
    with CameraClient(url, "tok") as cam:
        for p in range(4):
            cam.set_params(small, port=p)
        before = {p: {k: cam.params(p)[k] for k in TRIGGER} for p in range(4)}
    board.sim_timestamp_skew(2, 1_000_000)  # port 2 stamps its frames 1 ms late
    quad = tmp_path / "quad"
    r = run_cli(
        "tp", "capture", "--camera", url, "--token", "tok", "--out", str(quad),
        "--trigger-period-ms", "100",
    )  # fmt: skip
    assert r.returncode == 1 and r.stdout == ""
    # the progress lines up to the fetch, then the one-line error
    *steps, error = r.stderr.strip().splitlines()
    assert steps and all(line.startswith("tp capture: ") for line in steps), r.stderr
    assert steps[-1].startswith("tp capture: 7/8 ") and "fetched" in steps[-1]
    assert error.startswith("elphel: ") and "not of one trigger" in error and "+1.000 ms" in error
    assert list(tmp_path.iterdir()) == []  # no quad dir, no temporary leftovers
    with CameraClient(url, "tok") as cam:
        after = {p: {k: cam.params(p)[k] for k in TRIGGER} for p in range(4)}
    assert after == before
