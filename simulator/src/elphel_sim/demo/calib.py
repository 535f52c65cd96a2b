"""The demo's calibration step: the quad calibrated from a board, then depth from raw images.

As a user with a printed board does it (docs/calibration.md), through the `elphel` CLI:
the calibration rig (`elphel-sim up --scenario calib-small`: four 640x480 cameras, each
with its own lens, focal length and a rotation of about 0.4 degrees) is windowed, the
board is posed where `GET {sim_url}/board/poses` suggests (the hand's part, done through
the simulator's endpoint), and after each pose `elphel calibrate capture --quad` takes one
view; `elphel calibrate solve` calibrates the quad from them and draws the residual map.
The quad's standard scene is then rendered as those cameras record it (`elphel-sim
calib-scene`: distorted, each turned a little, the calibration named in quad.json), and
`elphel tp` computes three DSIs: the raw images with the calibration (and their depth),
the same raw images read as if the cameras were ideal, and the scene as ideal cameras
record it (the reference). Each is scored against the simulator's true disparity of
every tile, and the depth against the true depth.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import tifffile
from numpy.typing import NDArray
from PIL import Image

from elphel_host.preview import FAR_RGB, NO_VALUE_RGB, Swatch, map_picture, robust_range
from elphel_host.tp.io import QuadManifest
from elphel_sim.demo.rig import DemoError, elphel, elphel_sim, simulated_rig, step

VIEWS = 16  # enough for each plane's depth within 0.5 % whatever noise the frames have
MIN_CAMERAS = 3  # each suggested pose shows the whole board to at least 3 cameras
PATTERN = "checkerboard:9x6:25"
# `elphel` commands of this step: 4 windows, one capture per view, the solve, 3 DSIs.
COMMANDS = 4 + VIEWS + 1 + 3
STRENGTH_SHOWN = 0.15  # weaker DSI tiles are shown as having no texture
NEAR_DISPARITY_PX = 0.25  # depth is scored on nearer tiles (farther ones: beyond a km)
DEPTH_BAR_PCT = 2.0  # the depth error's colour bar: +-2 %, four times the 0.5 % aimed at


def calib_step(out: Path, *, seed: int) -> dict[str, Any]:
    """Calibrate the simulated quad from board views; DSI and depth from its raw images."""
    views, calib = out / "calib-views", out / "calib"
    shutil.rmtree(views, ignore_errors=True)  # new views from a new simulated rig
    step("starting the calibration rig (elphel-sim up --scenario calib-small)")
    with simulated_rig(seed=seed, scenario="calib-small") as rig:
        size, kept = capture_views(rig, views, seed=seed)
    step(f"calibration: solving the quad from {kept} views (elphel calibrate solve)")
    solved = elphel(
        "calibrate",
        "solve",
        str(views),
        "--pattern",
        PATTERN,
        "--out",
        str(calib),
        "--no-cross-validation",
    )
    residuals = calib / "residuals.png"
    per_camera = ", ".join(f"{c['rms_px']:.4f}" for c in solved["cameras"])
    step(
        f"calibration: residual {solved['rms_px']:.4f} px RMS (per camera {per_camera}); "
        f"residual map -> {residuals}"
    )
    quads = scene_quads(out, calib, size, seed=seed)
    return {
        "views_dir": str(views),
        "views": kept,
        "calibration": solved["calibration"],
        "rms_px": solved["rms_px"],
        "cameras": solved["cameras"],
        "warnings": solved["warnings"],
        "residuals_picture": str(residuals),
        **score_quads(out, quads),
    }


def capture_views(rig: dict[str, Any], views: Path, *, seed: int) -> tuple[tuple[int, int], int]:
    """Window the four cameras, pose the board ``VIEWS`` times, capture a view after each.

    Returns the cameras' image size (width, height) and the views kept.
    """
    sim = rig["sim_url"]
    camera = ("--camera", rig["camera_url"], "--token", rig["token"])
    window = httpx.get(f"{sim}/board", timeout=30).json()["window"]
    woi = [f"{k}={v}" for k, v in window.items()]
    for port in range(4):
        elphel("camera", "set", *camera, "--sensor-port", str(port), *woi)
    params = {"count": VIEWS, "seed": seed, "min_cameras": MIN_CAMERAS}
    poses = httpx.get(f"{sim}/board/poses", params=params, timeout=60).json()["poses"]
    if len(poses) < VIEWS:
        raise DemoError(f"{sim}/board/poses suggested {len(poses)} poses; allowed: {VIEWS}")
    step(
        f"calibration: posing the {PATTERN} board {VIEWS} times, a quad view after each "
        f"(elphel calibrate capture --quad, {window['WOI_WIDTH']}x{window['WOI_HEIGHT']})"
    )
    kept = 0
    for n in range(VIEWS):
        httpx.put(f"{sim}/board", json=poses[n], timeout=30).raise_for_status()
        got = elphel(
            "calibrate",
            "capture",
            *camera,
            "--quad",
            "--pattern",
            PATTERN,
            "--out",
            str(views),
            "--views",
            str(VIEWS),
            "--attempts",
            "1",
        )
        refused = [r["reason"] for r in got["not_kept"]]
        kept = int(got["views"])
        verdict = f"not kept: {refused[0]}" if refused else "kept"
        step(f"calibration: pose {n + 1}/{VIEWS}: {verdict} ({kept} views)")
    return (int(window["WOI_WIDTH"]), int(window["WOI_HEIGHT"])), kept


def scene_quads(out: Path, calib: Path, size: tuple[int, int], *, seed: int) -> dict[str, Path]:
    """The quad's scene as the calibrated cameras record it, read two ways, and as ideal ones.

    ``calibrated``: the raw images with the calibration in quad.json; ``as_ideal``: the
    same images without it (as if the cameras were ideal); ``rectified``: the scene
    recorded by ideal cameras. The raw directory's ``truth.json`` is the truth of all three.
    """
    raw, rect, plain = out / "calib-quad", out / "calib-quad-rectified", out / "calib-quad-plain"
    for d in (raw, rect, plain):
        shutil.rmtree(d, ignore_errors=True)
    step("calibration: rendering a scene as the quad's cameras record it (elphel-sim calib-scene)")
    elphel_sim(
        "calib-scene",
        str(raw),
        "--calibration",
        str(calib),
        "--rectified",
        str(rect),
        "--width",
        str(size[0]),
        "--height",
        str(size[1]),
        "--seed",
        str(seed),
    )
    manifest = QuadManifest.read(raw)
    plain.mkdir(parents=True)
    for cam in manifest.cameras:
        shutil.copyfile(raw / cam.file, plain / cam.file)
    replace(manifest, calibration=None).write(plain)
    return {"calibrated": raw, "as_ideal": plain, "rectified": rect}


def score_quads(out: Path, quads: dict[str, Path]) -> dict[str, Any]:
    """The three DSIs (depth of the calibrated one) against the truth; the picture."""
    from elphel_host.tp.dsi import read_dsi

    cloud = out / "calib-cloud.ply"
    calibrated = elphel(
        "tp", str(quads["calibrated"]), "--out", str(out / "calib-dsi.tif"), "--ply", str(cloud)
    )
    elphel("tp", str(quads["as_ideal"]), "--out", str(out / "calib-dsi-as-ideal.tif"))
    elphel("tp", str(quads["rectified"]), "--out", str(out / "calib-dsi-rectified.tif"))
    truth = json.loads((quads["calibrated"] / "truth.json").read_text())
    names = {"calibrated": "calib-dsi", "as_ideal": "calib-dsi-as-ideal"}
    names["rectified"] = "calib-dsi-rectified"
    layers = {k: read_dsi(out / f"{v}.tif")[0] for k, v in names.items()}
    rms = {k: dsi_rms_error_px(v["disparity"], truth) for k, v in layers.items()}
    depth_mm = np.asarray(tifffile.imread(calibrated["depth"]["depth_tiff"]), np.float64)
    depth = depth_errors(depth_mm, truth)
    picture = calib_picture(out / "calib-depth.png", layers, depth_mm, truth)
    ratio = rms["calibrated"] / rms["rectified"]
    step(
        f"calibration: DSI RMS error {rms['calibrated']:.4f} px with the calibration "
        f"({ratio:.2f}x the {rms['rectified']:.4f} px of ideal cameras), "
        f"{rms['as_ideal']:.2f} px for the same raw images read as ideal"
    )
    planes = ", ".join(f"{n} {e:+.2f} %" for n, e in depth["planes_pct"].items())
    step(
        f"calibration: depth against the truth: {planes}; median |error| "
        f"{depth['median_abs_pct']:.2f} % over {depth['tiles']} tiles -> {picture}"
    )
    return {
        "dsi": str(out / "calib-dsi.tif"),
        "cloud": str(cloud),
        "dsi_rms_error_px": {k: round(v, 4) for k, v in rms.items()},
        "calibrated_over_rectified": round(ratio, 3),
        "depth_error_pct": depth["planes_pct"],
        "depth_median_abs_error_pct": depth["median_abs_pct"],
        "depth_tiles": depth["tiles"],
        "picture": str(picture),
    }


def _scored(truth: dict[str, Any]) -> NDArray[np.bool_]:
    """Tiles whose disparity is defined and measurable: inside one textured region."""
    out: NDArray[np.bool_] = np.asarray(truth["interior"]) & np.asarray(truth["textured"])
    return out


def dsi_rms_error_px(disparity: NDArray[Any], truth: dict[str, Any]) -> float:
    """RMS of the DSI's error over the textured tiles inside one region (px)."""
    err = np.asarray(disparity, np.float64) - np.asarray(truth["disparity"], np.float64)
    return float(np.sqrt(np.mean(err[_scored(truth)] ** 2)))


def true_depth_mm(truth: dict[str, Any]) -> NDArray[np.float64]:
    """The true depth of every tile, ``f B / D`` (inf at infinity)."""
    d = np.asarray(truth["disparity"], np.float64)
    with np.errstate(divide="ignore"):
        out: NDArray[np.float64] = truth["focal_length_px"] * truth["baseline_mm"] / d
    return out


def depth_error_pct(depth_mm: NDArray[np.float64], truth: dict[str, Any]) -> NDArray[np.float64]:
    """Per tile, the depth's error against the truth in % (NaN where not scored)."""
    near = _scored(truth) & (np.asarray(truth["disparity"]) >= NEAR_DISPARITY_PX)
    with np.errstate(invalid="ignore", divide="ignore"):
        err = 100.0 * (depth_mm / true_depth_mm(truth) - 1.0)
    out: NDArray[np.float64] = np.where(near & np.isfinite(err), err, np.nan)
    return out


def depth_errors(depth_mm: NDArray[np.float64], truth: dict[str, Any]) -> dict[str, Any]:
    """Per region nearer than infinity the median depth error (%), and over all its tiles."""
    err = depth_error_pct(depth_mm, truth)
    label = np.asarray(truth["label"])
    planes = {}
    for index, name in enumerate(truth["names"]):
        tiles = err[(label == index) & np.isfinite(err)]
        if tiles.size:
            planes[name] = round(float(np.median(tiles)), 3)
    scored = err[np.isfinite(err)]
    if scored.size == 0:
        raise DemoError("no tile of the calibrated quad has a depth to score against the truth")
    return {
        "planes_pct": planes,
        "median_abs_pct": round(float(np.median(np.abs(scored))), 3),
        "tiles": int(scored.size),
    }


def calib_picture(
    path: Path,
    layers: dict[str, dict[str, NDArray[Any]]],
    depth_mm: NDArray[np.float64],
    truth: dict[str, Any],
) -> Path:
    """Raw read as ideal | raw + calibration | the truth (one bar, px) | the depth error (%)."""
    true_d = np.asarray(truth["disparity"], np.float64)
    # whole pixels and half a pixel of room: the background at 0 px is inside the bar
    low, high = robust_range(true_d)
    lo, hi = float(np.floor(low)) - 0.5, float(np.ceil(high)) + 0.5

    def dsi_panel(key: str, title: str) -> NDArray[np.uint8]:
        weak = ~(np.asarray(layers[key]["strength"]) >= STRENGTH_SHOWN)
        swatch = Swatch(f"no texture: strength < {STRENGTH_SHOWN}", weak, NO_VALUE_RGB)
        return map_picture(
            layers[key]["disparity"], lo=lo, hi=hi, unit="px", title=title, swatches=[swatch]
        )

    err = depth_error_pct(depth_mm, truth)
    far = (true_d < NEAR_DISPARITY_PX) & _scored(truth)
    panels = [
        dsi_panel("as_ideal", "raw images read as ideal"),
        dsi_panel("calibrated", "raw images + solved calibration"),
        map_picture(true_d, lo=lo, hi=hi, unit="px", title="true disparity (simulator)"),
        map_picture(
            err,
            lo=-DEPTH_BAR_PCT,
            hi=DEPTH_BAR_PCT,
            unit="%",
            title="depth error against the truth",
            swatches=[Swatch(f"far: disparity < {NEAR_DISPARITY_PX} px", far, FAR_RGB)],
            no_value="not scored (edge, no texture or left out)",
        ),
    ]
    height = max(p.shape[0] for p in panels)
    sheet = Image.new("RGB", (sum(p.shape[1] for p in panels), height), (255, 255, 255))
    x = 0
    for p in panels:
        sheet.paste(Image.fromarray(p), (x, 0))
        x += p.shape[1]
    sheet.save(path, optimize=True)
    return path
