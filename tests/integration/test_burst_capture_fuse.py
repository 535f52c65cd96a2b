"""`elphel burst capture --fuse` on the rig `elphel-sim up` serves, as a user runs it.

The fused file equals `elphel mfsr` on the finished burst; a fusion that cannot finish
keeps the captured frames and exits 1 with a one-line error.
"""

from __future__ import annotations

import json
import shutil
import time

import numpy as np
import pytest
import tifffile

from elphel_host.camera import CameraClient

from .rig import nominal_model, run_cli

# a small Bayer window near the optical centre keeps frames and fusion quick
WINDOW = {"WOI_LEFT": 1200, "WOI_TOP": 880, "WOI_WIDTH": 192, "WOI_HEIGHT": 160}
OPTICS = ("--focal-length-mm", "4.5", "--pixel-pitch-um", "2.2", "--distance-mm", "1000")


@pytest.fixture(scope="module")
def fused_burst(sim_rig, tmp_path_factory):
    """A 4-frame x2 burst captured with --fuse; yields (env, plan, burst dir, JSON result)."""
    env = {
        "ELPHEL_CAMERA_URL": sim_rig["camera_url"],
        "ELPHEL_CAMERA_TOKEN": sim_rig["token"],
        "ELPHEL_STAGE_URL": sim_rig["stage_url"],
    }
    tmp = tmp_path_factory.mktemp("fuse")
    with CameraClient(sim_rig["camera_url"], sim_rig["token"]) as cam:
        before = cam.params(0)
        cam.set_params(WINDOW)
        try:
            status = run_cli("stage", "status", "--json", env=env)
            assert status.returncode == 0, status.stderr
            if not json.loads(status.stdout)["homed"]:
                homed = run_cli("stage", "home", "--json", env=env)
                assert homed.returncode == 0, homed.stderr
            plan = tmp / "plan.json"
            planned = run_cli(
                *("burst", "plan", "--scale", "2", "--frames", "4", *OPTICS, "--out", str(plan)),
                env=env,
            )
            assert planned.returncode == 0, planned.stderr
            burst = tmp / "burst"
            model = str(nominal_model(tmp))
            done = run_cli(
                *("burst", "capture", "--plan", str(plan), "--out", str(burst)),
                *("--model", model, "--start-mm", "2", *OPTICS, "--fuse", "--json"),
                env=env,
            )
            assert done.returncode == 0, done.stderr
            yield env, plan, model, burst, json.loads(done.stdout), done.stderr
        finally:
            cam.set_params({k: before[k] for k in WINDOW})
            deadline = time.monotonic() + 30
            while cam.params(0)["WOI_WIDTH"] != before["WOI_WIDTH"]:
                assert time.monotonic() < deadline, "the full window did not come back"
                time.sleep(0.05)


def test_fused_file_equals_elphel_mfsr_on_the_finished_burst(fused_burst, tmp_path):
    env, _plan, _model, burst, result, stderr = fused_burst
    assert result["captured"] == [0, 1, 2, 3]
    fusion = result["fusion"]
    assert fusion["out"] == str(burst / "fused.tif") and fusion["used"] == 4
    assert fusion["method"] == "robust" and fusion["shape"] == [320, 384, 3]
    assert fusion["after_capture_s"] > 0
    # progress showed the fusion's state with each frame, then the end
    lines = stderr.splitlines()
    assert "burst: 4/4 " in lines[3] and "; fusion: registered " in lines[3]
    assert "reconstructing (robust x2)" in lines[4] and "after the last frame" in lines[5]
    post = tmp_path / "post.tif"
    posthoc = run_cli("mfsr", str(burst), "--scale", "2", "--out", str(post), "--json", env=env)
    assert posthoc.returncode == 0, posthoc.stderr
    mfsr = json.loads(posthoc.stdout)
    assert fusion["registration"] == mfsr["registration"]
    assert fusion["excluded"] == mfsr["excluded"] == []
    np.testing.assert_array_equal(tifffile.imread(burst / "fused.tif"), tifffile.imread(post))


def test_fusion_failure_keeps_the_frames_and_exits_1(fused_burst, tmp_path):
    env, plan, model, burst, _result, _stderr = fused_burst
    again = tmp_path / "burst"
    shutil.copytree(burst, again)
    for name in ("fused.tif", "fused.png"):
        (again / name).unlink()
    (again / "frames" / "0003.tif").unlink()  # resumed: frame 3 is captured again
    damaged = tifffile.imread(again / "frames" / "0001.tif").astype(np.uint8)
    tifffile.imwrite(again / "frames" / "0001.tif", damaged)  # one elphel mfsr refuses too
    r = run_cli(
        *("burst", "capture", "--plan", str(plan), "--out", str(again), "--model", model),
        *(*OPTICS, "--fuse", "--json"),
        env=env,
    )
    assert r.returncode == 1
    errors = [line for line in r.stderr.splitlines() if line.startswith("elphel:")]
    assert len(errors) == 1 and "fusion failed at frame 1" in errors[0]
    assert "dtype='uint8'; allowed: uint16" in errors[0]
    result = json.loads(r.stdout)
    assert result["captured"] == [3] and result["already_present"] == [0, 1, 2]
    assert result["fusion"]["error"] in errors[0]
    manifest = json.loads((again / "manifest.json").read_text())
    assert [e["file"] for e in manifest["frames"]] == [f"frames/{i:04d}.tif" for i in range(4)]
    assert sorted(p.name for p in again.iterdir()) == ["frames", "manifest.json"]
