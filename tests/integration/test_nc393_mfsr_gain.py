"""MFSR gain from a stock NC393's JP4 frames against elphel-camd's raw frames of the same scene.

The same sub-pixel burst (plan, window, stage start, seed) is captured through both
simulated cameras: elphel-camd (16-bit raw frames) and the stock NC393 (JP4 at quality 100
with Elphel's gamma 0.57, decoded back to linear). Each burst is fused and scored against
the simulator's truth on the output grid; the gain of the robust fusion over bicubic
up-sampling of one frame must agree within 0.5 dB, so the 8-bit JP4 code costs the fusion
no more than that. A stock NC393's frames have the black level subtracted (Elphel's
convention), so its truth is the scene minus the black level.
"""

import json
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import tifffile

from elphel_host.camera import connect
from elphel_sim.demo.report import reference_image
from elphel_sim.demo.rig import read_frame_metadata

from .rig import nominal_model, run_cli, start_rig, stop_rig

SEED = 5
WINDOW = {"WOI_LEFT": 1200, "WOI_TOP": 880, "WOI_WIDTH": 192, "WOI_HEIGHT": 160}
OPTICS = ("--focal-length-mm", "4.5", "--pixel-pitch-um", "2.2", "--distance-mm", "1000")
FRAMES = 8


def cli_json(*args: str, env: dict[str, str]) -> dict[str, Any]:
    r = run_cli(*args, "--json", env=env)
    assert r.returncode == 0, r.stderr
    result: dict[str, Any] = json.loads(r.stdout)
    return result


def burst_gain(out: Path, *firmware: str) -> dict[str, float]:
    """Capture the burst through one simulated camera; PSNR of bicubic and robust vs truth."""
    proc, rig = start_rig(*firmware, "--seed", str(SEED))
    try:
        env = {"ELPHEL_CAMERA_URL": rig["camera_url"], "ELPHEL_STAGE_URL": rig["stage_url"]}
        if rig.get("token"):
            env["ELPHEL_CAMERA_TOKEN"] = rig["token"]
        with connect(rig["camera_url"], token=rig.get("token")) as cam:
            cam.set_params(WINDOW, port=0)
        cli_json("stage", "home", env=env)
        plan = out / "plan.json"
        cli_json(
            *("burst", "plan", "--scale", "2", "--frames", str(FRAMES), "--bayer", *OPTICS),
            *("--out", str(plan)),
            env=env,
        )
        burst = out / "burst"
        cli_json(
            *("burst", "capture", "--plan", str(plan), "--out", str(burst)),
            *("--model", str(nominal_model(out)), "--start-mm", "2", *OPTICS),
            env=env,
        )
        first = json.loads((burst / "manifest.json").read_text())["frames"][0]
        truth = httpx.get(f"{rig['sim_url']}/ports/0/frames/{first['frame']}", timeout=10).json()
    finally:
        stderr = stop_rig(proc)
        assert proc.returncode == 0, f"elphel-sim up exited {proc.returncode}: {stderr}"
    _, meta = read_frame_metadata(burst / first["file"])
    truth_dn = reference_image(SEED, truth["carriage_mm"], meta, scale=2).astype(np.float64)
    if "black_level" in meta:
        # a stock NC393's frames have the black level subtracted (docs/formats.md); the
        # simulated sensor has no pedestal, so the truth on their scale is that much lower
        r, gr, gb, b = meta["black_level"]
        black = np.array([r, (gr + gb) / 2, b]) * (meta["full_scale_dn"] + 1)
        truth_dn = np.clip(truth_dn - black, 0, None)
    reference = out / "reference.tif"
    tifffile.imwrite(reference, np.rint(truth_dn).astype(np.uint16))
    compare = cli_json(
        *("mfsr", "compare", str(burst), "--scale", "2", "--reference", str(reference)),
        *("--out", str(out / "compare")),
        env={},
    )
    return {m: compare["methods"][m]["psnr_db"] for m in ("bicubic", "robust")}


@pytest.mark.slow  # two simulated rigs, two bursts, four fusions
def test_mfsr_gain_from_jp4_frames_matches_raw_frames(tmp_path: Path) -> None:
    (tmp_path / "camd").mkdir()
    (tmp_path / "nc393").mkdir()
    raw = burst_gain(tmp_path / "camd")
    jp4 = burst_gain(tmp_path / "nc393", "--firmware", "elphel")
    gain_raw = raw["robust"] - raw["bicubic"]
    gain_jp4 = jp4["robust"] - jp4["bicubic"]
    print(
        f"\nMFSR x2 gain over bicubic: elphel-camd {gain_raw:+.2f} dB "
        f"({raw['robust']:.2f} vs {raw['bicubic']:.2f}), stock NC393 JP4 {gain_jp4:+.2f} dB "
        f"({jp4['robust']:.2f} vs {jp4['bicubic']:.2f})"
    )
    assert gain_raw > 1.0, raw  # the fusion gains on the raw frames to begin with
    assert abs(gain_jp4 - gain_raw) <= 0.5
