"""docs/nc393.md's first block, as written, against a simulated stock NC393 on a busy host.

Only what a reader replaces by hand is replaced: the camera's address (the simulator's
``camera_url``) and the stage's serial port (the simulator's stage URL). Two CPU-bound
processes keep both cores busy meanwhile, as on a shared lab machine: every line up to
the burst capture (stage home, burst plan, burst capture) must exit 0. The quad line
(`tp capture`) is run against the same simulator by tests/integration/test_nc393_cli.py.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow


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
    env = {k: v for k, v in os.environ.items() if not k.startswith("ELPHEL_")}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    done = subprocess.run(
        ["bash", "-c", "set -e -o pipefail\n" + "\n".join(script) + "\n"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, f"{done.stdout}\n{done.stderr}"
    assert len(list((tmp_path / "burst" / "frames").glob("*.tif"))) == 4
    assert (tmp_path / "burst" / "manifest.json").is_file()
