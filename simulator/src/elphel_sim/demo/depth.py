"""The demo's last step: super-resolved depth from a quad burst on the simulated stage.

The quad camera rides the stage carriage in front of the relief scene
(`elphel-sim up --scenario quad-rig-small`: the scene in the centre 640x480 of the view).
Through the `elphel` CLI, as a user would: window the four sensors, home the stage, plan
16 positions, capture a quad burst (one trigger-synchronised set per position), run
`elphel depth` on it and `elphel tp --ply` on its first set alone (one low-resolution
quad), and score both clouds against the simulator's true surface with `elphel cloud
compare`. The picture puts the two depth maps and the truth side by side on one scale.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import tifffile
from numpy.typing import NDArray
from PIL import Image

from elphel_host.preview import map_picture, robust_range
from elphel_sim.demo.rig import elphel, rig_env, simulated_rig, step

# `elphel` commands of this step: 4 windows, home, plan, capture, tp, depth, 2 compares.
COMMANDS = 11
SCALE = 2
FRAMES = 16
# 16 positions 6.5 mm apart (98 mm of the simulated stage's 120 mm) from 10 mm: the back
# wall (disparity 1 px) moves 0.65 px over the burst, the nearest step (5.4 px) 3.5 px.
PLAN_DISTANCE_MM = 26000
START_MM = 10.0
OPTICS = ("--focal-length-mm", "4.5", "--pixel-pitch-um", "2.2")


def depth_step(out: Path, *, seed: int) -> dict[str, Any]:
    """Capture a quad burst on the simulated rig, fuse it into depth, score it on the truth."""
    step("starting the quad camera on the stage carriage (elphel-sim up --scenario quad-rig-small)")
    qb = out / "quad-burst"
    shutil.rmtree(qb, ignore_errors=True)  # a new burst from a new simulated rig
    with simulated_rig(seed=seed, scenario="quad-rig-small") as rig:
        scene, captured = capture_quad_burst(rig, out, qb)
        reference, truth = fetch_truth(rig, qb, out / "depth-reference.ply")
    lr_quad = first_set(qb, out / "quad-burst-set0")
    lr = elphel(
        "tp", str(lr_quad), "--out", str(out / "lr-dsi.tif"), "--ply", str(out / "lr-cloud.ply")
    )
    sr = elphel("depth", str(qb), "--scale", str(SCALE), "--out", str(out / "depth"))
    scores = {}
    for name, cloud in (("lr", out / "lr-cloud.ply"), ("mfsr", Path(sr["ply"]))):
        c = elphel(
            "cloud",
            "compare",
            str(cloud),
            str(reference),
            "--out-dir",
            str(out / f"depth-compare-{name}"),
        )
        scores[name] = c["compared_to_reference"]
    lr_s, sr_s = scores["lr"], scores["mfsr"]
    picture = depth_picture(
        out / "depth-lr-vs-mfsr.png",
        lr=(tifffile.imread(lr["depth"]["depth_tiff"]), lr_s),
        sr=(tifffile.imread(sr["depth_tiff"]), sr_s),
        truth=np.asarray(truth["disparity"], np.float64),
        optics=scene["optics"],
    )
    step(
        f"depth: one LR quad: {lr_s['points']} points, distance to the true surface mean "
        f"{lr_s['mean_mm'] / 1000:.2f} m, median {lr_s['median_mm'] / 1000:.2f} m"
    )
    step(
        f"depth: MFSR x{SCALE} (elphel depth, {sr['seconds']['total']:.1f} s): "
        f"{sr_s['points']} points, mean {sr_s['mean_mm'] / 1000:.2f} m, median "
        f"{sr_s['median_mm'] / 1000:.2f} m -> {picture}"
    )
    return {
        "quad_burst": str(qb),
        "capture_seconds": captured["seconds"],
        "depth": sr,
        "lr_cloud_to_truth": lr_s,
        "mfsr_cloud_to_truth": sr_s,
        "picture": str(picture),
    }


def capture_quad_burst(
    rig: dict[str, Any], out: Path, qb: Path
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Window the four sensors, home, plan and capture the quad burst ``qb``.

    Returns the simulator's quad scene and `elphel burst capture`'s result.
    """
    env = rig_env(rig)
    scene = httpx.get(f"{rig['sim_url']}/quad", timeout=30).json()
    geometry = out / "quad-rig-geometry.json"
    geometry.write_text(json.dumps(scene, indent=1) + "\n")
    window = [f"{k}={v}" for k, v in scene["window"].items()]
    for port in range(4):
        elphel("camera", "set", "--sensor-port", str(port), *window, env=env)
    elphel("stage", "home", env=env)
    plan_path = out / "quad-burst-plan.json"
    plan = elphel(
        "burst",
        "plan",
        "--scale",
        str(SCALE),
        "--bayer",
        "--frames",
        str(FRAMES),
        *OPTICS,
        "--distance-mm",
        str(PLAN_DISTANCE_MM),
        "--out",
        str(plan_path),
        env=env,
    )
    step(
        f"depth: {plan['frames']} carriage positions over {plan['travel_mm']:.1f} mm; "
        f"capturing a quad burst of {scene['window']['WOI_WIDTH']}x"
        f"{scene['window']['WOI_HEIGHT']} windows (elphel burst capture --quad)"
    )
    captured = elphel(
        "burst",
        "capture",
        "--plan",
        str(plan_path),
        "--quad",
        "--geometry",
        str(geometry),
        "--start-mm",
        str(START_MM),
        "--out",
        str(qb),
        env=env,
    )
    sets = len(captured["captured"])
    step(f"depth: {sets} quad sets captured in {captured['seconds']:.0f} s -> {qb}")
    return scene, captured


def fetch_truth(rig: dict[str, Any], qb: Path, reference: Path) -> tuple[Path, dict[str, Any]]:
    """The simulator's true surface seen from the burst's first carriage position.

    Writes the reference cloud to ``reference``; returns it and the true disparity maps.
    """
    manifest = json.loads((qb / "cam0" / "manifest.json").read_text())
    carriage = manifest["frames"][0]["caliper_mm"]
    r = httpx.get(
        f"{rig['sim_url']}/quad/reference.ply",
        params={"carriage_mm": carriage, "step_px": 0.5},
        timeout=120,
    )
    r.raise_for_status()
    reference.write_bytes(r.content)
    truth = httpx.get(f"{rig['sim_url']}/quad/truth", timeout=120).json()
    return reference, truth


def first_set(qb: Path, path: Path) -> Path:
    """The quad burst's first set as a quad directory (frame 0 of each camera)."""
    doc = json.loads((qb / "quad.json").read_text())
    shutil.rmtree(path, ignore_errors=True)
    path.mkdir(parents=True)
    for i, cam in enumerate(doc["cameras"]):
        burst = qb / cam["file"]
        frame = json.loads((burst / "manifest.json").read_text())["frames"][0]["file"]
        shutil.copyfile(burst / frame, path / f"cam{i}.tif")
        cam["file"] = f"cam{i}.tif"
    (path / "quad.json").write_text(json.dumps(doc, indent=1) + "\n")
    return path


def depth_picture(
    path: Path,
    *,
    lr: tuple[NDArray[Any], dict[str, Any]],
    sr: tuple[NDArray[Any], dict[str, Any]],
    truth: NDArray[np.float64],
    optics: dict[str, float],
) -> Path:
    """One LR quad's depth | the MFSR quad's | the truth, on one scale in metres."""
    f, b, pitch = optics["focal_length_mm"], optics["baseline_mm"], optics["pixel_pitch_um"]
    true_m = f * b / (np.where(truth > 0, truth, np.nan) * pitch / 1000.0) / 1000.0
    lo, hi = robust_range(true_m)

    def panel(depth_mm: NDArray[Any], cell: int, title: str) -> Image.Image:
        values = np.asarray(depth_mm, np.float64) / 1000.0
        picture = map_picture(
            values,
            lo=lo,
            hi=hi,
            unit="m",
            title=title,
            cell=cell,
            no_value="left out (weak, far or inconsistent)",
        )
        return Image.fromarray(picture)

    def scored(name: str, s: dict[str, Any]) -> str:
        return f"{name}: mean {s['mean_mm'] / 1000:.2f} m, median {s['median_mm'] / 1000:.2f} m"

    # the LR tile grid is half the MFSR one: twice the cell size shows both at one size
    panels = [
        panel(lr[0], 8, scored("one LR quad", lr[1])),
        panel(sr[0], 4, scored(f"MFSR x{SCALE}", sr[1])),
        panel(true_m * 1000.0, 8, "true depth (simulator)"),
    ]
    sheet = Image.new(
        "RGB", (sum(p.width for p in panels), max(p.height for p in panels)), (255, 255, 255)
    )
    x = 0
    for p in panels:
        sheet.paste(p, (x, 0))
        x += p.width
    sheet.save(path, optimize=True)
    return path
