"""Host CLI -> REST -> elphel-camd -> simulated I2C chip -> simulated frame, for every
sensor model of the simulator (the `mixed` scenario: MT9P006, MT9F002, Lepton 3.5)."""

import json

import numpy as np
import pytest
import tifffile

from .rig import run_cli, start_rig, stop_rig


@pytest.fixture(scope="module")
def mixed_rig():
    proc, announce = start_rig("--scenario", "mixed", "--seed", "3")
    try:
        yield {
            "ELPHEL_CAMERA_URL": announce["camera_url"],
            "ELPHEL_CAMERA_TOKEN": announce["token"],
        }
    finally:
        stderr = stop_rig(proc)
        print("\n".join(line for line in stderr.splitlines() if "no device" not in line))
        assert proc.returncode == 0, stderr


def test_every_sensor_model_end_to_end(mixed_rig, tmp_path):
    r = run_cli("camera", "info", "--json", env=mixed_rig)
    assert r.returncode == 0, r.stderr
    ports = {p["port"]: p["sensor"] for p in json.loads(r.stdout)["ports"]}
    models = {port: sensor["model"] for port, sensor in ports.items() if sensor}
    assert sorted(models.values()) == ["LEPTON35", "MT9F002", "MT9P006"]
    assert ports[3] is None
    for port, model in sorted(models.items()):
        start = []
        if model.startswith("MT9"):
            # A small window keeps the simulated render quick; a long exposure slows the
            # frames so the ring buffer (64 frames, 19 s) still holds the target frame when the
            # capture command starts.
            window = ["WOI_WIDTH=128", "WOI_HEIGHT=96", "WOI_LEFT=512", "WOI_TOP=384"]
            r = run_cli(
                *("camera", "set", "--sensor-port", str(port), *window, "EXPOS=300000", "--json"),
                env=mixed_rig,
            )
            assert r.returncode == 0, r.stderr
            start = ["--frame", str(json.loads(r.stdout)["frame"])]
        out = tmp_path / f"port{port}.tif"
        r = run_cli(
            *("camera", "capture", "--sensor-port", str(port), "--count", "2", *start),
            *("--out", str(out)),
            "--json",
            env=mixed_rig,
        )
        assert r.returncode == 0, r.stderr
        result = json.loads(r.stdout)
        stack = tifffile.imread(out)
        assert stack.dtype == np.uint16 and stack.shape[0] == 2
        assert result["metadata"]["sensor"] == model and result["metadata"]["port"] == port
        assert result["frames"][1] == result["frames"][0] + 1
        if start:
            assert result["frames"][0] == int(start[1]) and stack.shape[1:] == (96, 128)
        assert stack.max() > 0
