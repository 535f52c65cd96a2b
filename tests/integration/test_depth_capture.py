"""From the carriage-mounted quad to a scored point cloud, through the CLI as a user runs it.

`elphel-sim up --scenario quad-rig-small` (the relief scene in the centre 640x480 of the
view): window the four sensors as ``GET /quad`` says, home the stage, plan, capture a quad
burst (`elphel burst capture --quad`), `elphel depth` on it and `elphel tp --ply` on its
first set, then `elphel cloud compare` of both against the simulator's true surface.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from elphel_sim.demo.depth import first_set

from .rig import run_cli, running_rig

pytestmark = pytest.mark.slow  # two minutes of simulated stage moves and frames

FRAMES = 6


@pytest.fixture(scope="module")
def rig() -> Iterator[dict[str, Any]]:
    with running_rig("--scenario", "quad-rig-small", "--seed", "3") as info:
        yield info


def cli(*args: str, env: dict[str, str], timeout: float = 120) -> dict[str, Any]:
    done = run_cli(*args, "--json", env=env, timeout=timeout)
    assert done.returncode == 0, done.stderr
    result: dict[str, Any] = json.loads(done.stdout)
    return result


def test_quad_burst_to_depth_closer_to_the_truth_than_one_quad(
    rig: dict[str, Any], tmp_path: Path
) -> None:
    env = {
        "ELPHEL_CAMERA_URL": rig["camera_url"],
        "ELPHEL_CAMERA_TOKEN": rig["token"],
        "ELPHEL_STAGE_URL": rig["stage_url"],
    }
    quad = httpx.get(f"{rig['sim_url']}/quad", timeout=30).json()
    assert quad["image_size"] == [640, 480]
    geometry = tmp_path / "quad.json"
    geometry.write_text(json.dumps(quad))
    for port in range(4):
        cli("camera", "set", "--sensor-port", str(port),
            *(f"{k}={v}" for k, v in quad["window"].items()), env=env)  # fmt: skip
    cli("stage", "home", env=env)
    plan = tmp_path / "plan.json"
    cli("burst", "plan", "--scale", "2", "--bayer", "--frames", str(FRAMES),
        "--focal-length-mm", "4.5", "--pixel-pitch-um", "2.2", "--distance-mm", "26000",
        "--out", str(plan), env=env)  # fmt: skip
    qb = tmp_path / "qb"
    # 6 moves and quad sets: about 70 s alone, several times that beside other tests
    captured = cli("burst", "capture", "--plan", str(plan), "--quad", "--geometry",
                   str(geometry), "--start-mm", "10", "--out", str(qb), env=env,
                   timeout=600)  # fmt: skip
    assert captured["captured"] == list(range(FRAMES))
    frames = json.loads((qb / "cam2" / "manifest.json").read_text())["frames"]
    assert [f["index"] for f in frames] == list(range(FRAMES))
    reference = tmp_path / "reference.ply"
    r = httpx.get(
        f"{rig['sim_url']}/quad/reference.ply",
        params={"carriage_mm": frames[0]["caliper_mm"], "step_px": 1},
        timeout=120,
    )
    reference.write_bytes(r.content)

    depth = cli("depth", str(qb), "--scale", "2", "--out", str(tmp_path / "depth"), env=env)
    assert depth["method"] == "shift-and-add" and depth["tiles"] == 160 * 120
    assert depth["cameras"]["cam0"]["parallax_from"] == "caliper"
    first = first_set(qb, tmp_path / "set0")
    lr = cli("tp", str(first), "--out", str(tmp_path / "lr.tif"), "--ply",
             str(tmp_path / "lr.ply"), env=env)  # fmt: skip
    assert lr["depth"]["points"] > 0.9 * 80 * 60

    def median_m(cloud: str) -> float:
        c = cli("cloud", "compare", cloud, str(reference), "--out-dir", str(tmp_path), env=env)
        return float(c["compared_to_reference"]["median_mm"]) / 1000

    # measured: one LR quad 2.31 m, the fused 6-frame burst 1.15 m
    assert median_m(depth["ply"]) < 0.7 * median_m(str(tmp_path / "lr.ply"))
