"""docs/raspberry-pi.md, run where it needs no hardware: the unit it writes, the host's
commands against `elphel-sim up --scenario pi-pair` (two cameras, two daemons).

The host block is taken from the page as it is; only the `export` lines are replaced by
the rig's URLs and tokens in the same variables. Every other line must exit 0, and what
they leave behind must be the two-camera burst and its fused images the page describes,
each fused image beating bicubic up-sampling of its burst's first frame by 2 dB against
the simulator's truth: the scene seen from that camera's pose at the first frame by
pixels of half the pitch.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import tifffile
from numpy.typing import NDArray

from elphel_camd.sensors import imx219_registers as regs
from elphel_host.burst.io import read_burst
from elphel_host.camera.frames import read_tiff_metadata
from elphel_host.mfsr.fuse import fuse_frames
from elphel_host.mfsr.metrics import psnr
from elphel_sim.pytest_plugin import Rig
from elphel_sim.render import Intrinsics, render_radiance
from elphel_sim.scenarios import build
from tests.docs.test_shell_examples import sh_block

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "raspberry-pi.md"
pytestmark = pytest.mark.slow
SEED = 2
SCALE = 2  # the page's --scale


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


def truth(cam: int, carriage_mm: float, meta: dict[str, Any]) -> NDArray[np.float64]:
    """What camera ``cam`` sees at ``carriage_mm`` through its window, SCALE x finer, in DN."""
    scenario = build("pi-pair", seed=SEED)  # the rig's world: same scenario, same seed
    spec, world = scenario.ports[cam], scenario.world
    lr = spec.intrinsics
    cx, cy = lr.principal_point
    fine = Intrinsics(
        lr.focal_length_mm,
        lr.pixel_pitch_um / SCALE,
        lr.width * SCALE,
        lr.height * SCALE,
        cx * SCALE,
        cy * SCALE,
    )
    left, top = regs.ACTIVE_LEFT + meta["WOI_LEFT"], regs.ACTIVE_TOP + meta["WOI_TOP"]
    window = (left * SCALE, top * SCALE, meta["WOI_WIDTH"] * SCALE, meta["WOI_HEIGHT"] * SCALE)
    world.rig.carriage_mm = carriage_mm
    rgb = render_radiance(world, fine, world.camera_pose(spec.mount), window=window)
    dn = rgb * meta["EXPOS"] * spec.sensor.electrons_per_us * spec.sensor.dn_per_e
    return np.clip(dn, 0, (1 << spec.sensor.bits) - 1)


def gain_over_bicubic_db(rig: Rig, cam: int, burst_dir: Path, fused: NDArray[Any]) -> float:
    """PSNR of the page's fused image minus that of bicubic, against the simulator's truth."""
    burst = read_burst(burst_dir)
    first = burst.infos[0]
    _, meta = read_tiff_metadata((burst_dir / first.file).read_bytes())
    pose = httpx.get(f"{rig.sim_url}/ports/{cam}/frames/{first.frame}", timeout=30).json()
    ref = truth(cam, float(pose["carriage_mm"]), meta)
    bicubic = fuse_frames(burst.frames[:1], scale=SCALE, method="bicubic", bayer=burst.bayer)

    def score(image: NDArray[Any]) -> float:
        span = float(ref.max() - ref.min())
        luma = np.asarray(image, np.float64).mean(axis=2)
        return psnr(ref.mean(axis=2), luma, data_range=span, border=4 * SCALE)

    return score(fused) - score(bicubic.image)


@pytest.mark.elphel_rig(scenario="pi-pair", seed=SEED)
def test_host_commands_capture_both_cameras_and_fuse_each(elphel_rig: Rig, tmp_path: Path) -> None:
    rig = elphel_rig
    assert len(rig.camera_urls) == 2 and len(set(rig.tokens)) == 2
    assert rig.camera_urls[0] == rig.camera_url
    lines = [ln for ln in sh_block(PAGE, "## 4. From the host") if not ln.startswith("export ")]
    assert any('--camera "$CAM1"' in ln and "burst capture" in ln for ln in lines)
    env = {k: v for k, v in os.environ.items() if not k.startswith("ELPHEL_")}
    env |= {
        "CAM0": rig.camera_urls[0],
        "TOKEN0": rig.tokens[0] or "",
        "CAM1": rig.camera_urls[1],
        "TOKEN1": rig.tokens[1] or "",
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
    positions, gains_db = [], []
    for cam in (0, 1):
        manifest = json.loads((tmp_path / "pair" / f"cam{cam}" / "manifest.json").read_text())
        assert manifest["rig_camera"] == cam and manifest["bayer"] == "RGGB"
        assert len(manifest["frames"]) == len(plan["positions_mm"])
        positions.append([f["stage_mm"] for f in manifest["frames"]])
        fused = tifffile.imread(tmp_path / f"cam{cam}-x2.tif")
        assert fused.shape[:2] == (960, 1280)
        gains_db.append(gain_over_bicubic_db(rig, cam, tmp_path / "pair" / f"cam{cam}", fused))
    assert positions[0] == positions[1]
    assert min(gains_db) >= 2.0, gains_db
