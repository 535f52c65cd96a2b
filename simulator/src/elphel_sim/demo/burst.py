"""The demo's burst steps: a x2 Bayer burst, and the same through a blurred lens.

The first is captured, fused and scored against the simulator's truth; the second is
captured by a rig whose lens blurs (`elphel-sim up --lens-blur`) and fused without being
told the blur.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import httpx

from elphel_sim.demo.report import burst_crops, reference_image
from elphel_sim.demo.rig import elphel, read_frame_metadata, rig_env, simulated_rig, step

# The `elphel` commands of these steps (the demo's progress bar counts them).
COMMANDS = 9

# A 576 x 432 window at the centre keeps the burst quick; the fusion itself scales
# to full frames (see docs/mfsr.md for its 16 x 1640 x 1232 figures).
WINDOW = {"WOI_LEFT": 1008, "WOI_TOP": 756, "WOI_WIDTH": 576, "WOI_HEIGHT": 432}
SCALE = 2
FRAMES = 16
DISTANCE_MM = 1000.0


OPTICS = ("--focal-length-mm", "4.5", "--pixel-pitch-um", "2.2", "--distance-mm", f"{DISTANCE_MM}")
# The second burst's lens: a Gaussian blur of 0.35 sensor px (0.7 px of the x2 output)
LENS_BLUR_PX = 0.35


def write_reference(rig: dict[str, Any], burst: Path, path: Path, *, seed: int) -> Path:
    """The simulator's truth for ``burst`` on the fused grid (a perfectly sharp lens)."""
    import tifffile

    first = json.loads((burst / "manifest.json").read_text())["frames"][0]
    truth = httpx.get(f"{rig['sim_url']}/ports/0/frames/{first['frame']}", timeout=10).json()
    _, meta = read_frame_metadata(burst / first["file"])
    tifffile.imwrite(path, reference_image(seed, truth["carriage_mm"], meta, scale=SCALE))
    return path


def gain_over_bicubic(compare: dict[str, Any]) -> float:
    methods = compare["methods"]
    return round(methods["robust"]["psnr_db"] - methods["bicubic"]["psnr_db"], 3)


def capture_args(plan_path: str, burst: Path) -> tuple[str, ...]:
    """`elphel burst capture` of ``plan_path`` into ``burst`` from 40 mm, with the optics."""
    return (
        "burst",
        "capture",
        "--plan",
        plan_path,
        "--out",
        str(burst),
        "--start-mm",
        "40",
        *OPTICS,
    )


def compare_args(burst: Path, reference: Path, out_dir: Path) -> tuple[str, ...]:
    """`elphel mfsr compare` of ``burst`` against ``reference``, written to ``out_dir``."""
    return (
        "mfsr",
        "compare",
        str(burst),
        "--scale",
        str(SCALE),
        "--reference",
        str(reference),
        "--out",
        str(out_dir),
    )


def burst_step(
    rig: dict[str, Any], out: Path, stage: dict[str, Any], *, seed: int
) -> dict[str, Any]:
    """Plan, capture and fuse the x2 Bayer burst; score it against the simulator's truth."""
    env = rig_env(rig)
    elphel("camera", "set", *(f"{k}={v}" for k, v in WINDOW.items()), env=env)
    plan_path = out / "burst-plan.json"
    plan = elphel(
        "burst",
        "plan",
        "--scale",
        str(SCALE),
        "--frames",
        str(FRAMES),
        *OPTICS,
        "--mm-per-step",
        f"{stage['mm_per_step']}",
        "--bayer",
        "--out",
        str(plan_path),
    )
    step(f"burst: x{SCALE} Bayer plan, {plan['frames']} frames over {plan['travel_mm']:.3f} mm")
    burst = out / "burst"
    # `burst capture` resumes a directory of the same plan and refuses another plan's;
    # each demo run captures a new burst from a new simulated rig
    shutil.rmtree(burst, ignore_errors=True)
    captured = elphel(*capture_args(str(plan_path), burst), "--model", stage["model"], env=env)
    step(f"burst: {len(captured['captured'])} frames captured in {captured['seconds']:.1f} s")
    ref_path = write_reference(rig, burst, out / "burst-reference.tif", seed=seed)
    fused = elphel("mfsr", str(burst), "--scale", str(SCALE), "--out", str(out / "fused.tif"))
    compare = elphel(*compare_args(burst, ref_path, out / "mfsr-compare"))
    scores = ", ".join(
        f"{m} {r['psnr_db']:.2f} dB SSIM {r['ssim']:.3f}"
        for m, r in compare["methods"].items()
        if r.get("psnr_db") is not None
    )
    step(f"burst: against the simulator's truth: {scores} -> {out / 'fused.tif'}")
    crops = burst_crops(out / "mfsr-compare", ref_path, out / "burst-crops.png")
    step(f"burst: crops bicubic | baseline | robust | reference -> {crops}")
    return {
        "plan": str(plan_path),
        "burst": str(burst),
        "fused": fused,
        "compare": compare,
        "gain_over_bicubic_db": gain_over_bicubic(compare),
        "crops_png": str(crops),
    }


def lens_blur_step(out: Path, sharp: dict[str, Any], *, seed: int) -> dict[str, Any]:
    """The same burst through a blurred lens (`elphel-sim up --lens-blur`), fused and scored.

    The fusion is not told the blur: its default estimates it from the burst. The truth
    is the same sharp scene; the gain over bicubic is set beside the sharp lens's.
    """
    step(f"starting a simulated rig whose lens blurs (elphel-sim up --lens-blur {LENS_BLUR_PX})")
    burst, cmp_dir = out / "burst-lens-blur", out / "mfsr-compare-lens-blur"
    shutil.rmtree(burst, ignore_errors=True)
    with simulated_rig(seed=seed, lens_blur_px=LENS_BLUR_PX) as rig:
        env = rig_env(rig)
        elphel("camera", "set", *(f"{k}={v}" for k, v in WINDOW.items()), env=env)
        elphel("stage", "home", env=env)
        elphel(*capture_args(sharp["plan"], burst), env=env)
        ref_path = write_reference(rig, burst, out / "burst-lens-blur-reference.tif", seed=seed)
    compare = elphel(*compare_args(burst, ref_path, cmp_dir))
    psf = compare["methods"]["robust"].get("psf", {})
    gain, sharp_gain = gain_over_bicubic(compare), sharp["gain_over_bicubic_db"]
    step(
        f"burst through a lens blur of {LENS_BLUR_PX} px: robust over bicubic {gain:+.2f} dB "
        f"(sharp lens {sharp_gain:+.2f} dB); blur found {psf.get('apparent_sigma_hr_px')} "
        f"output px, {psf.get('sigma_hr_px')} of it deconvolved -> {cmp_dir}"
    )
    return {
        "lens_blur_px": LENS_BLUR_PX,
        "burst": str(burst),
        "compare": compare,
        "gain_over_bicubic_db": gain,
        "sharp_lens_gain_over_bicubic_db": sharp_gain,
    }
