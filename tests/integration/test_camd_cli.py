"""Full path: `elphel camera ...` and the Python client -> REST -> elphel-camd -> simulated
I2C chip -> simulated frame, on the rig `elphel-sim up` serves."""

import contextlib
import json
import subprocess
import sys
import time

import numpy as np
import pytest
import tifffile

from elphel_host.camera import CameraClient, CameraHTTPError

from .rig import run_cli

WINDOW = {"WOI_WIDTH": 96, "WOI_HEIGHT": 64, "WOI_LEFT": 1200, "WOI_TOP": 900}
# A 150 ms exposure makes frames long: the ring buffer (64 frames) then spans 10 s, time
# enough to start a CLI process.
SLOW = {"EXPOS": 150_000}


@pytest.fixture
def rig(sim_rig):
    """The session's rig, put back to its full window afterwards (other tests capture it)."""
    env = {"ELPHEL_CAMERA_URL": sim_rig["camera_url"], "ELPHEL_CAMERA_TOKEN": sim_rig["token"]}
    with CameraClient(sim_rig["camera_url"], sim_rig["token"]) as cam:
        before = cam.params(0)
        try:
            yield env
        finally:
            cam.set_params({k: before[k] for k in (*WINDOW, "EXPOS", "GAINR", "PF_HEIGHT")})
            deadline = time.monotonic() + 30
            while cam.params(0)["WOI_WIDTH"] != before["WOI_WIDTH"]:
                assert time.monotonic() < deadline, "the full window did not come back"
                time.sleep(0.05)


def test_cli_set_get_capture_through_the_simulated_chip(rig, tmp_path):
    assignments = [f"{k}={v}" for k, v in {**WINDOW, **SLOW}.items()]
    r = run_cli("camera", "set", *assignments, "GAINR=0x10000", "--ahead", "4", "--json", env=rig)
    assert r.returncode == 0, r.stderr
    applied = json.loads(r.stdout)
    assert applied["params"]["WOI_WIDTH"] == 96
    target = applied["frame"]

    r = run_cli("camera", "get", "WOI_WIDTH", "EXPOS", "--frame", str(target), "--json", env=rig)
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout)
    assert got == {"WOI_WIDTH": 96, "EXPOS": applied["params"]["EXPOS"]}

    out = tmp_path / "burst.tif"
    r = run_cli("camera", "capture", "--count", "3", "--out", str(out), "--json", env=rig)
    assert r.returncode == 0, r.stderr
    result = json.loads(r.stdout)
    stack = tifffile.imread(out)
    assert stack.shape == (3, 64, 96) and stack.dtype == np.uint16
    frames = result["frames"]
    assert frames == list(range(frames[0], frames[0] + 3)) and frames[0] >= target
    assert result["metadata"]["sensor"] == "MT9P006"
    assert stack.max() > 0  # the simulated scene, not an empty buffer

    # The same frame again after the fact, from the daemon's ring buffer.
    again = tmp_path / "again.tif"
    r = run_cli("camera", "capture", "--frame", str(frames[1]), "--out", str(again), env=rig)
    assert r.returncode == 0, r.stderr
    assert np.array_equal(tifffile.imread(again), stack[1])

    r = run_cli("camera", "set", "WOI_WIDTH=3", "--json", env=rig)
    assert r.returncode == 1 and r.stdout == ""
    assert "422" in r.stderr and "WOI_WIDTH" in r.stderr and "even" in r.stderr


def test_cli_joins_photofinish_composites_with_row_times(rig, tmp_path):
    photofinish = {**WINDOW, "PF_HEIGHT": 2, "EXPOS": 100}
    assignments = [f"{k}={v}" for k, v in photofinish.items()]
    r = run_cli("camera", "set", *assignments, "--ahead", "4", "--json", env=rig)
    assert r.returncode == 0, r.stderr
    out = tmp_path / "pf.tif"
    r = run_cli("camera", "capture", "--count", "3", "--join", "--out", str(out), "--json", env=rig)
    assert r.returncode == 0, r.stderr
    result = json.loads(r.stdout)
    with tifffile.TiffFile(out) as tif:
        image = tif.asarray()
        metadata = json.loads(tif.pages.first.description)
    assert image.shape == (3 * 64, 96) and image.dtype == np.uint16
    assert metadata["frames"] == result["frames"] and len(result["frames"]) == 3
    strips = metadata["pf_strips"]
    assert strips == 32 and metadata["PF_HEIGHT"] == 2
    times = np.array(metadata["pf_strip_times_ns"])
    assert len(times) == 3 * strips and times[0] == metadata["timestamp_ns"]
    # One strip period between every two strips, across the composites' joins too.
    assert np.all(np.diff(times) == metadata["pf_strip_period_ns"])


def test_cli_watch_prints_frames_and_changes(rig):
    with CameraClient(rig["ELPHEL_CAMERA_URL"], rig["ELPHEL_CAMERA_TOKEN"]) as cam:
        cam.set_params({**WINDOW, **SLOW})
    r = run_cli("camera", "watch", "--types", "frame", "--count", "4", "--json", env=rig)
    assert r.returncode == 0, r.stderr
    events = json.loads(r.stdout)["events"]
    numbers = [e["frame"] for e in events]
    assert [e["type"] for e in events] == ["frame"] * 4
    assert numbers == list(range(numbers[0], numbers[0] + 4))

    watcher = subprocess.Popen(
        [
            *(sys.executable, "-m", "elphel_host.cli", "camera", "watch"),
            *("--types", "params", "--count", "1", "--camera", rig["ELPHEL_CAMERA_URL"]),
            *("--token", rig["ELPHEL_CAMERA_TOKEN"]),  # reads need it too
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        with CameraClient(rig["ELPHEL_CAMERA_URL"], rig["ELPHEL_CAMERA_TOKEN"]) as cam:
            deadline = time.monotonic() + 60
            while watcher.poll() is None and time.monotonic() < deadline:
                cam.set_params({"GAINR": 0x18000})  # until the watcher has subscribed
                with contextlib.suppress(subprocess.TimeoutExpired):
                    watcher.wait(timeout=0.5)
        out, err = watcher.communicate(timeout=30)
    finally:
        if watcher.poll() is None:
            watcher.kill()
            watcher.communicate()
    assert watcher.returncode == 0, err
    assert out.startswith("params port 0") and "GAINR=98304" in out


def test_python_client_staged_restores_and_reports_errors(rig):
    with CameraClient(rig["ELPHEL_CAMERA_URL"], rig["ELPHEL_CAMERA_TOKEN"]) as cam:
        before = cam.params(0)
        with cam.staged({"EXPOS": 2000, "FLIPV": 1}) as applied:
            assert applied[0].params["FLIPV"] == 1
        after = cam.params(0, frame=cam.frame(0)["frame"] + 14)
        assert (after["EXPOS"], after["FLIPV"]) == (before["EXPOS"], before["FLIPV"])
        with pytest.raises(CameraHTTPError) as err:
            cam.set_params({"GAINR": 1})
        assert err.value.status == 422 and err.value.parameter == "GAINR"
        assert err.value.value == 1 and err.value.allowed
        assert cam.health()["status"] == "ok"
        reg = cam.register(0x00)
        assert reg["name"] == "chip_version" and reg["value"] == 0x1801
        events = list(cam.events(("frame",), count=2))
        assert [e.type for e in events] == ["frame", "frame"]
