"""docs/nc393.md's first block, as written, against a simulated stock NC393 on a busy host.

Only what a reader replaces by hand is replaced: the camera's address (the simulator's
``camera_url``) and the stage's serial port (the simulator's stage URL). Two CPU-bound
processes keep both cores busy meanwhile, as on a shared lab machine: every line up to
the burst capture (stage home, burst plan, burst capture) must exit 0, and so must the
quad line (`tp capture` at the default trigger period, then `tp`), within `QUAD_BUDGET_S`.
For that test the simulated sensors take a small window first and each port sends one
frame (what the camera was set to and did before; the quad line itself does not touch the
window), so that the four frames and the DSI are quick to make and the simulator's
forming processes are warm, as a real camera has none to start: it is the trigger period
chosen from a timed fetch, on a busy host, that it checks.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from elphel_host.camera import connect

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow
# A centred window of the quad scenario's MT9P006 (2592 x 1944): whole JP4 macroblocks.
QUAD_WINDOW = {"WOI_WIDTH": 256, "WOI_HEIGHT": 192, "WOI_LEFT": 1168, "WOI_TOP": 876}
QUAD_BUDGET_S = 90.0  # the quad line beside two busy loops, on the lab machine


def first_sh_block(page: Path) -> list[str]:
    """The commands of the page's first ``sh`` block, continuation lines joined."""
    body = re.search(r"```sh\n(.*?)```", page.read_text(), flags=re.S)
    assert body is not None, f"{page.name}: no sh block"
    text = body.group(1).replace("\\\n", " ")
    lines = [line.split("  #", 1)[0].strip() for line in text.splitlines()]
    return [line for line in lines if line and not line.startswith("#")]


@pytest.fixture
def busy_host() -> Iterator[None]:
    spin = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        yield
    finally:
        for proc in spin:
            proc.kill()
            proc.wait()


def run_script(
    lines: list[str], cwd: Path, *, timeout_s: float
) -> subprocess.CompletedProcess[str]:
    """Run shell lines as a reader would (set -e), the venv's commands first on PATH."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("ELPHEL_")}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    return subprocess.run(
        ["bash", "-c", "set -e -o pipefail\n" + "\n".join(lines) + "\n"],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout_s,
    )


@pytest.mark.elphel_rig(scenario="quad", firmware="elphel")
def test_the_stock_camera_page_runs_as_written(elphel_rig, busy_host, tmp_path: Path) -> None:
    lines = first_sh_block(ROOT / "docs" / "nc393.md")
    assert lines[0].startswith("CAM=nc393://")
    wanted = ("stage home", "burst plan", "burst capture", "tp capture")
    assert all(any(w in line for line in lines) for w in wanted), lines
    burst = next(i for i, line in enumerate(lines) if "burst capture" in line)
    script = [f"CAM='{elphel_rig.camera_url}'"] + [
        line.replace("/dev/ttyUSB0", elphel_rig.stage_url) for line in lines[1 : burst + 1]
    ]
    done = run_script(script, tmp_path, timeout_s=900)
    assert done.returncode == 0, f"{done.stdout}\n{done.stderr}"
    assert len(list((tmp_path / "burst" / "frames").glob("*.tif"))) == 4
    assert (tmp_path / "burst" / "manifest.json").is_file()


@pytest.mark.elphel_rig(scenario="quad", firmware="elphel")
def test_the_quad_line_runs_as_written_on_a_busy_host(elphel_rig, tmp_path: Path) -> None:
    lines = first_sh_block(ROOT / "docs" / "nc393.md")
    quad = [line for line in lines if "tp capture" in line]
    assert len(quad) == 1 and "tp quad/" in quad[0], quad
    with connect(elphel_rig.camera_url) as camera:
        for port in range(4):
            camera.set_params(QUAD_WINDOW, port=port)
        for port in range(4):
            camera.capture(port)
    script = [f"CAM='{elphel_rig.camera_url}'", quad[0]]
    spin = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        done = run_script(script, tmp_path, timeout_s=QUAD_BUDGET_S)
    finally:
        for proc in spin:
            proc.kill()
            proc.wait()
    assert done.returncode == 0, f"{done.stdout}\n{done.stderr}"
    assert "to fetch" in done.stderr and "trigger period" in done.stderr, done.stderr
    assert len(list((tmp_path / "quad").glob("cam?.tif"))) == 4
    assert (tmp_path / "dsi.tif").is_file()
