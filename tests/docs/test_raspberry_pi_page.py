"""docs/raspberry-pi.md, run where it needs no hardware: the unit it writes, the host's
commands against `elphel-sim up --scenario pi-pair` (two cameras, two daemons).

The host block is taken from the page as it is; only the `export` lines are replaced by
the rig's URLs and tokens in the same variables. Every other line must exit 0, and what
they leave behind must be the two-camera burst and its fused images the page describes.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import tifffile

from tests.docs.test_shell_examples import sh_block

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "raspberry-pi.md"
pytestmark = pytest.mark.slow


def unit_command(out: Path) -> str:
    """The page's command that writes the service unit, writing to ``out`` instead."""
    text = PAGE.read_text()
    start = text.index("sed -e 's|@BINDIR@|")
    end = text.index("| sudo tee /etc/systemd/system/elphel-camd.service")
    return text[start:end].replace("\\\n", " ") + f"> {out}"


def test_the_unit_runs_the_v4l2_board_on_the_network_with_video_access(tmp_path: Path) -> None:
    env = {**os.environ, "PATH": f"/usr/bin:/bin:{os.environ.get('PATH', '')}"}
    done = subprocess.run(
        ["bash", "-c", f"hostname() {{ echo pi0; }}\n{unit_command(tmp_path / 'unit')}"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert done.returncode == 0, done.stderr
    unit = (tmp_path / "unit").read_text()
    assert "@" not in unit.replace("multi-user.target", "")
    exec_start = re.search(r"^ExecStart=(.*)$", unit, flags=re.M)
    assert exec_start is not None
    assert exec_start.group(1) == (
        "/opt/elphel-camd/bin/elphel-camd --board v4l2 --video /dev/video0 "
        "--host 0.0.0.0 --allow-host pi0.local"
    )
    assert "SupplementaryGroups=i2c video" in unit
    assert "EnvironmentFile=-/etc/default/elphel-camd" in unit


@pytest.mark.elphel_rig(scenario="pi-pair", seed=2)
def test_host_commands_capture_both_cameras_and_fuse_each(elphel_rig, tmp_path: Path) -> None:
    rig = elphel_rig
    assert len(rig.camera_urls) == 2 and len(set(rig.tokens)) == 2
    assert rig.camera_urls[0] == rig.camera_url
    lines = [ln for ln in sh_block(PAGE, "## 4. From the host") if not ln.startswith("export ")]
    assert any('--camera "$CAM1"' in ln and "burst capture" in ln for ln in lines)
    env = {k: v for k, v in os.environ.items() if not k.startswith("ELPHEL_")}
    env |= {
        "CAM0": rig.camera_urls[0],
        "TOKEN0": rig.tokens[0],
        "CAM1": rig.camera_urls[1],
        "TOKEN1": rig.tokens[1],
        "ELPHEL_STAGE_URL": rig.stage_url,
        "HOME": str(tmp_path),  # the stage model's default place
        "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
    }
    for line in lines:
        done = subprocess.run(
            ["bash", "-c", f"set -e -o pipefail\n{line}\n"],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert done.returncode == 0, f"{line}\n{done.stdout}\n{done.stderr}"
    plan = json.loads((tmp_path / "plan.json").read_text())
    positions = []
    for cam in (0, 1):
        manifest = json.loads((tmp_path / "pair" / f"cam{cam}" / "manifest.json").read_text())
        assert manifest["rig_camera"] == cam and manifest["bayer"] == "RGGB"
        assert len(manifest["frames"]) == len(plan["positions_mm"])
        positions.append([f["stage_mm"] for f in manifest["frames"]])
        fused = tifffile.imread(tmp_path / f"cam{cam}-x2.tif")
        assert fused.shape[:2] == (960, 1280)
    assert positions[0] == positions[1]
