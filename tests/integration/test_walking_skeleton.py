"""End to end: `elphel-sim up` serves a board; the `elphel` CLI reads and captures from it."""

import json

import numpy as np
import tifffile

from .rig import run_cli


def test_announcement_names_the_services(sim_rig):
    assert sim_rig["camera_url"].startswith("http://127.0.0.1:")
    assert sim_rig["sim_url"].startswith("http://127.0.0.1:")
    assert len(sim_rig["token"]) >= 16
    assert {"stage_url", "stage_pty"} <= sim_rig.keys()


def test_camera_info_json_reports_sensor_read_over_i2c(sim_rig):
    r = run_cli(
        "camera", "info", "--camera", sim_rig["camera_url"], "--token", sim_rig["token"], "--json"
    )
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout)  # exactly one JSON object
    assert info["board"] == "sim"
    assert info["ports"][0]["sensor"]["model"] == "MT9P006"
    assert info["ports"][0]["sensor"]["chip_id"] == 0x1801


def test_camera_capture_writes_16bit_tiff_and_preview(sim_rig, tmp_path):
    out = tmp_path / "frame.tif"
    png = tmp_path / "frame.png"
    env = {"ELPHEL_CAMERA_URL": sim_rig["camera_url"], "ELPHEL_CAMERA_TOKEN": sim_rig["token"]}
    r = run_cli("camera", "capture", "--out", str(out), "--png", str(png), "--json", env=env)
    assert r.returncode == 0, r.stderr
    result = json.loads(r.stdout)
    image = tifffile.imread(out)
    assert image.dtype == np.uint16
    assert image.shape == (1944, 2592) == tuple(result["shape"])
    assert result["metadata"]["sensor"] == "MT9P006"
    assert png.stat().st_size > 10_000


def test_capture_without_token_fails_with_one_line_error(sim_rig, tmp_path):
    r = run_cli(
        "camera", "capture", "--camera", sim_rig["camera_url"], "--out", str(tmp_path / "x.tif")
    )
    assert r.returncode == 1
    assert r.stdout == ""
    assert "401" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x.tif").exists()


def test_unreachable_camera_is_a_clear_error():
    r = run_cli("camera", "info", "--camera", "http://127.0.0.1:9")
    assert r.returncode == 1
    assert "cannot reach the camera" in r.stderr


def test_usage_error_exits_2():
    r = run_cli("camera", "info", env={"ELPHEL_CAMERA_URL": ""})  # no URL anywhere
    assert r.returncode == 2
