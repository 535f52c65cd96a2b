"""`make demo`: the main job on the simulator, end to end.

Starts a simulated rig with `elphel-sim up` and drives it only through what a user has:
the `elphel` CLI and the REST API. Steps: detect the sensor and capture a frame; home and
calibrate the stage and check it against the simulator's truth; capture a sub-pixel burst
and fuse it, and the same burst again through a blurred lens (`elphel-sim up
--lens-blur`; both in `elphel_sim.demo.burst`); capture one trigger-synchronised set
from the simulated quad camera (`elphel-sim up --scenario quad`) and compute its
disparity map; calibrate a quad of distorted, turned cameras from views of a board and
compute its DSI and depth from their raw images (`elphel_sim.demo.calib`); read a
recording of a simulated stock NC393; and last, put the quad on the stage carriage,
capture a quad burst and turn it into super-resolved depth (`elphel_sim.demo.depth`).
Everything goes under ``out/`` with a summary a person can read (``summary.json`` and the
printed lines). The rig and the user's tools the steps go through are in `elphel_sim.demo.rig`.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from numpy.typing import NDArray

from elphel_host.camera import CameraClient
from elphel_host.preview import (
    FAR_RGB,
    NO_VALUE_RGB,
    Swatch,
    robust_range,
    save_map_picture,
    save_preview,
)
from elphel_sim.demo.burst import COMMANDS as BURST_COMMANDS
from elphel_sim.demo.burst import burst_step, lens_blur_step
from elphel_sim.demo.calib import COMMANDS as CALIB_COMMANDS
from elphel_sim.demo.calib import calib_step
from elphel_sim.demo.depth import COMMANDS as DEPTH_COMMANDS
from elphel_sim.demo.depth import depth_step
from elphel_sim.demo.rig import (
    DEMO_PROGRESS,
    DemoError,
    elphel,
    read_frame_metadata,
    simulated_rig,
    step,
)

# The `elphel` commands the demo runs (stage 2, quad 2, stock NC393 2, and the burst,
# calibration and depth steps'): the progress bar counts them.
COMMANDS = 6 + BURST_COMMANDS + CALIB_COMMANDS + DEPTH_COMMANDS

# -- camera -----------------------------------------------------------------------------------


def camera_step(rig: dict[str, Any], out: Path) -> dict[str, Any]:
    with CameraClient(rig["camera_url"], rig["token"]) as camera:
        info = camera.info()
        sensors = {
            str(p["port"]): p["sensor"]["model"] if p["sensor"] else None for p in info["ports"]
        }
        for port, model in sensors.items():
            step(f"port {port}: {model or 'no sensor'} (detected over simulated I2C)")
        t0 = time.monotonic()
        frame = camera.capture(0)
        elapsed = time.monotonic() - t0
    tif = out / "frame.tif"
    tif.write_bytes(frame.tiff)
    bayer = frame.metadata.get("bayer")
    png = save_preview(frame.image, out / "frame.png", bayer=bayer)
    save_preview(frame.image, out / "frame-mosaic.png", bayer=bayer, mosaic=True)
    h, w = frame.image.shape
    step(f"captured frame {frame.frame}: {w}x{h} {frame.image.dtype} in {elapsed:.1f} s -> {tif}")
    return {
        "board": info["board"],
        "sensors": sensors,
        "capture": {
            "file": str(tif),
            "preview": str(png),
            "shape": [h, w],
            "dtype": str(frame.image.dtype),
            "mean_dn": round(float(np.mean(frame.image)), 1),
            "seconds": round(elapsed, 2),
            "metadata": frame.metadata,
        },
    }


def stock_camera_step(out: Path, *, seed: int) -> dict[str, Any]:
    """One frame from a simulated stock NC393 (parsedit.php + imgsrv, JP4), as a user takes it."""
    step("starting a simulated stock NC393 (elphel-sim up --firmware elphel)")
    with simulated_rig(seed=seed, firmware="elphel") as rig:
        url = rig["camera_url"]
        info = elphel("camera", "info", "--camera", url)
        model = info["ports"][0]["sensor"]["model"]
        tif, png = out / "nc393-frame.tif", out / "nc393-frame.png"
        t0 = time.monotonic()
        got = elphel("camera", "capture", "--camera", url, "--out", str(tif), "--png", str(png))
        elapsed = time.monotonic() - t0
    _, meta = read_frame_metadata(tif)
    step(
        f"stock NC393 at {url}: port 0 {model}; frame {meta['frame']} came as "
        f"{meta['source'].upper()} (quality {meta['quality']}, gamma {meta['gamma'][0]}), "
        f"decoded to linear {meta['full_scale_dn'] + 1}-level data in {elapsed:.1f} s -> {tif}"
    )
    return {"camera_url": url, "sensor": model, "capture": got, "metadata": meta}


# -- stage ------------------------------------------------------------------------------------


def stage_step(rig: dict[str, Any], out: Path) -> dict[str, Any]:
    env = {"ELPHEL_STAGE_URL": rig["stage_url"]}
    model = str(out / "stage-model.json")
    step("stage: homing and calibrating mm/step with the caliper (a minute)")
    cal = elphel("stage", "calibrate", "--model", model, env=env)
    truth = httpx.get(f"{rig['sim_url']}/stage", timeout=10).json()
    error_pct = 100 * (cal["mm_per_step"] - truth["mm_per_step"]) / truth["mm_per_step"]
    step(
        f"stage: {cal['mm_per_step']:.7f} mm/step measured, {truth['mm_per_step']} true "
        f"({error_pct:+.3f} %)"
    )
    target = 42.0
    move = elphel("stage", "move", f"{target}", "--model", model, env=env)
    truth = httpx.get(f"{rig['sim_url']}/stage", timeout=10).json()
    miss_mm = truth["true_mm"] - truth.get("caliper_zero_mm", 0.0) - target
    step(f"stage: closed-loop move to {target} mm ended {miss_mm * 1000:+.1f} µm from target")
    return {
        "mm_per_step": cal["mm_per_step"],
        "mm_per_step_true": truth["mm_per_step"],
        "calibration_error_pct": round(error_pct, 4),
        "closed_loop_target_mm": target,
        "closed_loop_caliper_mm": move["caliper_mm"],
        "closed_loop_true_error_um": round(miss_mm * 1000, 2),
        "model": model,
    }


# -- quad / tile processor --------------------------------------------------------------------

STRENGTH_SHOWN = 0.15  # DSI tiles weaker than this are shown as having no texture
MIN_DEPTH_DISPARITY_PX = 0.25


def capture_quad(rig: dict[str, Any], out: Path) -> tuple[dict[str, Any], Path, dict[str, Any]]:
    """One trigger-synchronised quad set; returns the scene, the quad directory, the truth."""
    scene = httpx.get(f"{rig['sim_url']}/quad", timeout=30).json()
    geometry = out / "quad-geometry.json"
    geometry.write_text(json.dumps(scene, indent=1) + "\n")
    step("quad: capturing four 2592x1944 Bayer frames of one trigger (elphel tp capture)")
    quad_dir = out / "quad"
    camera = ["--camera", rig["camera_url"], "--token", rig["token"]]
    capture = elphel(
        "tp", "capture", *camera, "--geometry", str(geometry), "--out", str(quad_dir), "--force"
    )
    frames = ", ".join(f"port {p} #{f}" for p, f in capture["frames"].items())
    step(
        f"quad: one trigger at t={capture['timestamp_ns']} ns ({frames}) in "
        f"{capture['seconds']:.1f} s -> {quad_dir}"
    )
    truth = httpx.get(f"{rig['sim_url']}/quad/truth", timeout=120).json()
    return scene, quad_dir, truth


def region_errors(
    err: NDArray[np.float64], truth: dict[str, Any], scene: dict[str, Any]
) -> dict[str, Any]:
    """Per named region of the scene: its textured interior tiles and their RMS error."""
    true_disparity = np.asarray(truth["disparity"], dtype=np.float64)
    label = np.asarray(truth["label"])
    interior, textured_tiles = np.asarray(truth["interior"]), np.asarray(truth["textured"])
    depth_mm = {r["name"]: r["depth_mm"] for r in scene["regions"]}
    regions: dict[str, Any] = {}
    for index, name in enumerate(truth["names"]):
        mask = (label == index) & interior & textured_tiles
        if mask.any():
            true_d = float(np.median(true_disparity[mask]))
            regions[name] = {
                "tiles": int(mask.sum()),
                "true_disparity_px": round(true_d, 3),
                "depth_m": round(depth_mm[name] / 1000, 1) if name in depth_mm else None,
                "rms_error_px": round(float(np.sqrt(np.mean(err[mask] ** 2))), 4),
            }
    return regions


def save_quad_pictures(
    out: Path,
    disparity: NDArray[np.floating[Any]],
    strength: NDArray[np.floating[Any]],
    true_disparity: NDArray[np.float64],
    optics: dict[str, float],
) -> None:
    """disparity.png, disparity-truth.png and depth.png of the quad's DSI.

    Both disparity maps share one bar (the robust range of the truth), so they compare;
    texture-less tiles and far ones (whose depth is mostly noise) are named in the legends.
    """
    weak = ~(strength >= STRENGTH_SHOWN)
    no_texture = Swatch(f"no texture: strength < {STRENGTH_SHOWN}", weak, NO_VALUE_RGB)
    lo, hi = robust_range(true_disparity)
    bar = {"lo": lo, "hi": hi, "unit": "px", "cell": 2}
    save_map_picture(
        disparity, out / "disparity.png", title="disparity (DSI)", swatches=[no_texture], **bar
    )
    save_map_picture(
        true_disparity, out / "disparity-truth.png", title="true disparity (simulator)", **bar
    )
    # Depth of a tile: Z = f * B / (D * pitch), B the square's side (optics of quad.json).
    # Below MIN_DEPTH_DISPARITY_PX the depth is beyond a km and dominated by the error.
    with np.errstate(invalid="ignore"):
        far = ~weak & ~(disparity > MIN_DEPTH_DISPARITY_PX)
    near = np.where(weak | far, np.nan, disparity)
    depth_m = (
        optics["focal_length_mm"]
        * optics["baseline_mm"]
        / (near * optics["pixel_pitch_um"] / 1000.0)
        / 1000.0
    )
    far_m = (
        optics["focal_length_mm"]
        * optics["baseline_mm"]
        / (MIN_DEPTH_DISPARITY_PX * optics["pixel_pitch_um"] / 1000.0)
        / 1000.0
    )
    far_swatch = Swatch(
        f"far: disparity < {MIN_DEPTH_DISPARITY_PX} px, beyond {far_m:.0f} m", far, FAR_RGB
    )
    save_map_picture(
        depth_m,
        out / "depth.png",
        unit="m",
        title="depth from the DSI",
        swatches=[far_swatch, no_texture],
        cell=2,
    )


def quad_step(out: Path, *, seed: int) -> dict[str, Any]:
    """The quad camera of the simulator: one synchronised set captured, then its DSI."""
    from elphel_host.tp.dsi import read_dsi

    step("starting the simulated quad camera (elphel-sim up --scenario quad)")
    with simulated_rig(seed=seed, scenario="quad") as rig:
        scene, quad_dir, truth = capture_quad(rig, out)
    dsi_path = out / "dsi.tif"
    result = elphel("tp", str(quad_dir), "--out", str(dsi_path))
    layers, _ = read_dsi(dsi_path)
    disparity = layers["disparity"]
    true_disparity = np.asarray(truth["disparity"], dtype=np.float64)
    err = disparity - true_disparity
    regions = region_errors(err, truth, scene)
    textured = np.asarray(truth["interior"]) & np.asarray(truth["textured"])
    rms_all = float(np.sqrt(np.mean(err[textured] ** 2)))
    save_quad_pictures(out, disparity, layers["strength"], true_disparity, scene["optics"])
    step(
        f"quad: DSI {result['tiles_x']}x{result['tiles_y']} tiles in {result['seconds']:.2f} s; "
        f"RMS error {rms_all:.3f} px over {int(textured.sum())} textured tiles -> {dsi_path}"
    )
    for name, r in regions.items():
        step(f"  {name:12s} true {r['true_disparity_px']:6.3f} px  RMS {r['rms_error_px']:.4f} px")
    return {
        "dsi": str(dsi_path),
        "picture": str(out / "disparity.png"),
        "truth_picture": str(out / "disparity-truth.png"),
        "depth_picture": str(out / "depth.png"),
        "seconds": result["seconds"],
        "rms_error_px": round(rms_all, 4),
        "regions": regions,
    }


# -- the whole job ----------------------------------------------------------------------------


def run(out: Path, *, seed: int) -> dict[str, Any]:
    out.mkdir(parents=True, exist_ok=True)
    DEMO_PROGRESS.total = COMMANDS
    summary: dict[str, Any] = {"seed": seed}
    step("starting the simulated rig (elphel-sim up)")
    with simulated_rig(seed=seed) as rig:
        step(f"camera daemon at {rig['camera_url']}, stage at {rig['stage_url']}")
        summary["camera"] = camera_step(rig, out)
        summary["stage"] = stage_step(rig, out)
        summary["burst"] = burst_step(rig, out, summary["stage"], seed=seed)
    summary["burst_lens_blur"] = lens_blur_step(out, summary["burst"], seed=seed)
    summary["quad"] = quad_step(out, seed=seed)
    summary["calibration"] = calib_step(out, seed=seed)
    summary["stock_nc393"] = stock_camera_step(out, seed=seed)
    summary["depth"] = depth_step(out, seed=seed)
    (out / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=True) + "\n")
    step(f"wrote {out / 'summary.json'}")
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="elphel-sim-demo", description="Run the main job on the simulator."
    )
    p.add_argument("--out", type=Path, default=Path("out"), help="output folder (default out/)")
    p.add_argument("--seed", type=int, default=0, help="seed of every noise source")
    args = p.parse_args(argv)
    try:
        run(args.out, seed=args.seed)
    except (OSError, DemoError, ValueError, httpx.HTTPError) as e:
        print(f"demo: {e}", file=sys.stderr)
        return 1
    return 0
