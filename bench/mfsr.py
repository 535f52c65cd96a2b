"""MFSR benchmark: prints exactly one JSON object.

Synthetic bursts from scikit-image sample images bundled in its wheel (no downloads):
HR image in [0, 1] -> bicubic sub-pixel shift -> area down-sampling -> Gaussian noise
sigma 0.01, all seeded; plus bursts rendered by the simulator (elphel_sim world/render:
area-integrated pixels of a band-limited textured plane, camera moved sideways; the
reference is the same scene seen by a sensor with S times finer pixels).
PSNR/SSIM against the HR image with a 4*S px border cropped.
Blurred bursts: the same scenes through an optical Gaussian blur of sigma 0.5, 0.7 and
1.0 HR px (before the pixel integration; the method is not told), scored against the
sharp HR image. robust is the default (``--psf auto``: the blur estimated from the burst;
the estimate and its error are reported), robust_no_psf the pixel aperture alone
(``--psf none``, the robust method before the blur estimate), both with bicubic and
baseline in the same run; the blur-free bursts report robust_no_psf as well.
Field-varying blur: the photographs through a lens blurring 0.4 HR px on the axis to 1.2
at the corners; one PSF estimated (the default) against one per region given (the lens's
own, as a 4-D PSF file); see _mfsr_optics.py.
Bayer bursts: three RGB photographs as GRBG mosaics, x2, the 16 frames of the Bayer plan
(``elphel burst plan --bayer``), noise 0.01, sharp and through a 0.7 HR px lens blur;
PSNR per colour against the RGB truth, averaged over the colours.
The speed test fuses, in a fresh process per method (peak memory = that process's max
RSS, including the frames it loads), each method twice in turns, the faster run
reported: 16 mono frames of 1640x1232 to 3280x2464 through a 0.7 HR px lens blur; 16
GRBG frames of 1640x1232 (the Bayer plan, the same blur) to RGB 3280x2464; and 16 GRBG
frames of 640x480 (the README's window) to RGB 1280x960.

Usage: python bench/mfsr.py [--quick] [--no-speed] [--no-blur]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from _mfsr_optics import (
    NO_PSF,
    SIGMA,
    Maker,
    blurred,
    crop_to,
    field_varying,
    gaussian_blur,
    load,
    mean_db,
    summarise_blurred,
    summarise_field_varying,
)

from elphel_host.burst.plan import plan_burst
from elphel_host.mfsr.fuse import fuse_frames, peak_memory_mb
from elphel_host.mfsr.metrics import psnr, ssim
from elphel_host.mfsr.registration import register_frames
from elphel_host.mfsr.robust import reconstruct
from elphel_host.mfsr.synth import (
    area_downsample,
    make_bayer_burst,
    make_burst,
    random_shifts,
    tilted_line_shifts,
)

IMAGES = ("camera", "astronaut", "brick", "text", "coins", "moon")
RGB_IMAGES = ("astronaut", "coffee", "chelsea")
SPEED_RUNS = 2
SPEED_BLUR = 0.7  # HR px, the lens of the speed bursts (no method is told)
BAYER = "GRBG"


def rms(est: list[Any], truth: np.ndarray) -> float:
    e = np.asarray(est, dtype=np.float64) - truth
    return float(np.sqrt(np.mean(np.sum(e[1:] ** 2, axis=1))))


def image_maker(name: str) -> Maker:
    """Bursts from a scikit-image sample image: bicubic shift + area down-sampling + noise."""
    hr0 = load(name)

    def make(
        shifts: np.ndarray, s: int, seed: int, blur: float = 0.0
    ) -> tuple[list[np.ndarray], np.ndarray]:
        hr = crop_to(hr0, s)
        seen = gaussian_blur(hr, blur)
        return make_burst(seen, shifts, scale=s, noise_sigma=SIGMA, seed=seed), hr

    return make


def simulator_maker(size: int = 192) -> Maker:
    """Bursts rendered by the simulator: a textured plane at 500 mm, camera moved sideways.

    The reference is the same scene rendered by a sensor with S times more pixels of 1/S
    the pitch, which puts its pixel centres exactly on the cv2.resize grid of the LR one.
    """
    import skimage.data as sd

    from elphel_sim.render import Intrinsics, render_radiance
    from elphel_sim.world import Plane, Pose, Scene, Texture, World

    tex = Texture.from_image(sd.camera(), period_mm=6.0)
    world = World(scene=Scene(planes=[Plane(texture=tex, origin=(-3.0, -3.0, 500.0))]))
    f_mm, pitch, z = 35.0, 2.2, 500.0

    def make(
        shifts: np.ndarray, s: int, seed: int, blur: float = 0.0
    ) -> tuple[list[np.ndarray], np.ndarray]:
        lr = Intrinsics(focal_length_mm=f_mm, pixel_pitch_um=pitch, width=size, height=size)
        hi = Intrinsics(
            focal_length_mm=f_mm, pixel_pitch_um=pitch / s, width=size * s, height=size * s
        )
        px_per_mm = lr.focal_length_px / z
        rng = np.random.default_rng(seed)
        frames = []
        for dy, dx in shifts:
            pose = Pose.at((dx / px_per_mm, dy / px_per_mm, 0.0))
            if blur > 0:
                # the optics blur the image before the pixels integrate it: render by
                # S-times finer pixels, blur, then sum S x S of them into one pixel
                fine = render_radiance(world, hi, pose)[..., 1].astype(np.float32)
                img = area_downsample(gaussian_blur(fine, blur), s)
            else:
                img = render_radiance(world, lr, pose)[..., 1]
            frames.append((img + rng.normal(0, SIGMA, img.shape)).astype(np.float32))
        hr = render_radiance(world, hi, Pose.at((0.0, 0.0, 0.0)))[..., 1].astype(np.float32)
        return frames, hr

    return make


def quality(makers: dict[str, Maker], seed: int) -> dict[str, Any]:
    per: dict[str, Any] = {}
    for n_img, (name, make) in enumerate(makers.items()):
        row: dict[str, Any] = {}
        for s in (2, 4):
            b = 4 * s
            shifts = random_shifts(16, seed=seed + n_img, spread=2.0)
            frames, hr = make(shifts, s, seed + 100 + n_img)
            rng_ = float(hr.max() - hr.min()) if name == "simulator" else 1.0
            res = {
                m: fuse_frames(frames, scale=s, method=m)
                for m in (("bicubic", "baseline", "robust") if s == 2 else ("bicubic", "robust"))
            }
            res["robust_no_psf"] = fuse_frames(frames, scale=s, method="robust", config=NO_PSF)
            r = {
                m: {
                    "psnr_db": round(psnr(hr, v.image, data_range=rng_, border=b), 3),
                    "ssim": round(ssim(hr, v.image, data_range=rng_, border=b), 4),
                }
                for m, v in res.items()
            }
            regs = register_frames(frames)
            r["registration_rms_lr_px"] = round(rms([g.shift for g in regs], shifts), 4)
            r["registration_refined_rms_lr_px"] = round(
                rms(res["robust"].info["shifts_refined"], shifts), 4
            )
            r["psf"] = res["robust"].info["psf"]
            row[f"x{s}"] = r
        # 1-D stage with the recommended tilt vs random 2-D offsets (x2, 16 frames, robust)
        for key, line in (
            ("x2_tilted_line_psnr_db", tilted_line_shifts(16, scale=2)),
            ("x2_untilted_line_psnr_db", np.stack([np.zeros(16), np.arange(16) / 8.0], axis=1)),
        ):
            frames, hr = make(line, 2, seed + 200 + n_img)
            rng_ = float(hr.max() - hr.min()) if name == "simulator" else 1.0
            regs = register_frames(frames)
            img, _ = reconstruct(frames, [g.shift for g in regs], scale=2)
            row[key] = round(psnr(hr, img, data_range=rng_, border=8), 3)
        per[name] = row
    return per


def summarise(per: dict[str, Any]) -> dict[str, Any]:
    def gains(s: str, a: str, b: str) -> list[float]:
        return [v[s][a]["psnr_db"] - v[s][b]["psnr_db"] for v in per.values()]

    g2b = gains("x2", "robust", "bicubic")
    g2base = gains("x2", "robust", "baseline")
    g4b = gains("x4", "robust", "bicubic")
    base2 = gains("x2", "baseline", "bicubic")
    tilt = [v["x2"]["robust"]["psnr_db"] - v["x2_tilted_line_psnr_db"] for v in per.values()]
    untilt = [v["x2"]["robust"]["psnr_db"] - v["x2_untilted_line_psnr_db"] for v in per.values()]
    reg = [v["x2"]["registration_rms_lr_px"] for v in per.values()]
    regr = [v["x2"]["registration_refined_rms_lr_px"] for v in per.values()]
    out = {
        "x2_registration_rms_lr_px_ecc": round(float(np.sqrt(np.mean(np.square(reg)))), 4),
        "x2_registration_rms_lr_px_refined": round(float(np.sqrt(np.mean(np.square(regr)))), 4),
        "x2_robust_gain_over_bicubic_db_mean": mean_db(g2b),
        "x2_robust_gain_over_baseline_db_mean": mean_db(g2base),
        "x2_robust_gain_over_baseline_db_min": round(float(np.min(g2base)), 3),
        "x2_baseline_gain_over_bicubic_db_mean": mean_db(base2),
        "x4_robust_gain_over_bicubic_db_mean": mean_db(g4b),
        "x4_robust_gain_over_bicubic_db_min": round(float(np.min(g4b)), 3),
        "x2_tilted_line_loss_vs_2d_db_mean": mean_db(tilt),
        "x2_tilted_line_loss_vs_2d_db_max": round(float(np.max(tilt)), 3),
        "x2_untilted_line_loss_vs_2d_db_mean": mean_db(untilt),
    }
    for s in ("x2", "x4"):  # the blur estimate against the pixel aperture alone, blur-free
        d = gains(s, "robust", "robust_no_psf")
        out[f"{s}_robust_minus_no_psf_db_mean"] = mean_db(d)
        out[f"{s}_robust_minus_no_psf_db_min"] = round(float(np.min(d)), 3)
    return out


def bayer_shifts() -> np.ndarray:
    """The 16 shifts (LR px) of the x2 Bayer plan (``elphel burst plan --bayer``)."""
    plan = plan_burst(
        scale=2, focal_length_mm=35, pixel_pitch_um=2.2, distance_mm=500, frames=16, bayer=True
    )
    return np.asarray(plan.shifts_px, dtype=np.float64)


def load_rgb(name: str, size: tuple[int, int] | None = None) -> np.ndarray:
    """A scikit-image RGB photograph in [0, 1], resized to ``size`` (width, height)."""
    import skimage.data as sd

    rgb = np.asarray(getattr(sd, name)(), np.float32) / 255.0
    if size is not None:
        rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_CUBIC)
    h, w = rgb.shape[0] // 4 * 4, rgb.shape[1] // 4 * 4  # whole Bayer cells at x2
    return np.ascontiguousarray(np.clip(rgb[:h, :w], 0, 1), dtype=np.float32)


def bayer_quality(seed: int) -> dict[str, Any]:
    """Bayer bursts (GRBG, x2, the Bayer plan): PSNR per method, mean over the colours."""
    per: dict[str, Any] = {}
    shifts = bayer_shifts()
    for n_img, name in enumerate(RGB_IMAGES):
        hr = load_rgb(name)
        row: dict[str, Any] = {}
        for blur in (0.0, SPEED_BLUR):
            seen = np.stack([gaussian_blur(hr[..., c], blur) for c in range(3)], axis=-1)
            frames = make_bayer_burst(
                seen, shifts, scale=2, noise_sigma=SIGMA, seed=seed + 400 + 3 * n_img, bayer=BAYER
            )
            scores = {}
            for m in ("bicubic", "baseline", "robust"):
                img = fuse_frames(frames, scale=2, method=m, bayer=BAYER).image
                db = [psnr(hr[..., c], img[..., c], data_range=1.0, border=8) for c in range(3)]
                scores[m] = round(float(np.mean(db)), 3)
            row[f"sigma_{blur}"] = scores
        per[name] = row
    return per


def summarise_bayer(per: dict[str, Any]) -> dict[str, Any]:
    def gains(a: str, b: str) -> list[float]:
        return [v[k][a] - v[k][b] for v in per.values() for k in v]

    return {
        "robust_gain_over_bicubic_db_mean": mean_db(gains("robust", "bicubic")),
        "robust_gain_over_baseline_db_mean": mean_db(gains("robust", "baseline")),
        "robust_gain_over_baseline_db_min": round(float(np.min(gains("robust", "baseline"))), 3),
    }


def speed_child(path: str, method: str) -> None:
    frames = list(np.load(path))
    meta = json.loads(Path(path).with_suffix(".json").read_text())
    truth = np.asarray(meta["shifts"])
    bayer = meta["bayer"]
    t0 = time.perf_counter()
    c0 = resource.getrusage(resource.RUSAGE_SELF)
    if method == "robust_no_psf":
        res = fuse_frames(frames, scale=2, method="robust", bayer=bayer, config=NO_PSF)
    else:
        res = fuse_frames(frames, scale=2, method=method, bayer=bayer)
    dt = time.perf_counter() - t0
    c1 = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
    out = {
        "seconds": round(dt, 3),
        "cpu_seconds": round(cpu, 3),
        "excluded": res.excluded,
        "shape": list(res.image.shape),
        "peak_rss_mb": round(peak_memory_mb(), 1),
    }
    if bayer is None:  # mono: how well each method found the shifts
        if method.startswith("robust"):
            est = res.info["shifts_refined"]
        else:
            est = [s if s is not None else [np.nan, np.nan] for s in res.info["shifts"]]
        out["registration_rms_lr_px"] = round(rms(est, truth), 4)
    print(json.dumps(out))


def race(frames: np.ndarray, shifts: np.ndarray, bayer: str | None, methods: tuple[str, ...]):
    """Each method on ``frames`` in fresh processes, SPEED_RUNS times in turns, the faster run.

    A fresh process's first run after the burst is made was seen 1.7x slower than the
    same run next, hence the turns.
    """
    out: dict[str, Any] = {"input": list(frames.shape), "bayer": bayer}
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "frames.npy"
        np.save(p, frames)
        meta = {"shifts": np.asarray(shifts).tolist(), "bayer": bayer}
        p.with_suffix(".json").write_text(json.dumps(meta))
        for _ in range(SPEED_RUNS):
            for method in methods:
                cp = subprocess.run(
                    [sys.executable, __file__, "--speed-child", str(p), method],
                    capture_output=True,
                    text=True,
                    check=True,
                )
                run = json.loads(cp.stdout)
                if method not in out or run["seconds"] < out[method]["seconds"]:
                    out[method] = run
    out["runs_per_method"] = SPEED_RUNS
    for m in methods[:-1]:  # the last is the peer
        key = (
            "speedup_vs_baseline"
            if m == "robust"
            else f"{m.removeprefix('robust_')}_speedup_vs_baseline"
        )
        out[key] = round(out["baseline"]["seconds"] / out[m]["seconds"], 2)
        out["cpu_" + key] = round(out["baseline"]["cpu_seconds"] / out[m]["cpu_seconds"], 2)
    return out


def speed(seed: int, which: tuple[str, ...]) -> dict[str, Any]:
    """Robust against the baseline on the same frames in one run: mono, Bayer, Bayer 640x480."""
    out: dict[str, Any] = {}
    if "mono" in which:
        big = cv2.resize(load("astronaut"), (3280, 2464), interpolation=cv2.INTER_CUBIC)
        rng = np.random.default_rng(seed)
        tex = cv2.GaussianBlur(rng.normal(0, 1, big.shape).astype(np.float32), (0, 0), 1.0)
        hr = gaussian_blur(np.clip(big + 0.08 * tex, 0, 1).astype(np.float32), SPEED_BLUR)
        shifts = random_shifts(16, seed=seed, spread=2.0)
        frames = np.stack(make_burst(hr, shifts, scale=2, noise_sigma=SIGMA, seed=seed + 1))
        del big, tex, hr
        out["mono"] = race(frames, shifts, None, ("robust", "robust_no_psf", "baseline"))
        del frames
    shifts = bayer_shifts()
    for key, size in (("bayer", (3280, 2464)), ("bayer_640x480", (1280, 960))):
        if key not in which:
            continue
        rgb = load_rgb("astronaut", size)
        rgb = np.stack([gaussian_blur(rgb[..., c], SPEED_BLUR) for c in range(3)], axis=-1)
        frames = np.stack(
            make_bayer_burst(rgb, shifts, scale=2, noise_sigma=SIGMA, seed=seed + 2, bayer=BAYER)
        )
        del rgb
        out[key] = race(frames, shifts, BAYER, ("robust", "baseline"))
        del frames
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="three images only")
    ap.add_argument("--no-speed", action="store_true")
    ap.add_argument("--no-blur", action="store_true", help="skip the bursts through a lens")
    ap.add_argument(
        "--speed",
        nargs="+",
        choices=("mono", "bayer", "bayer_640x480"),
        default=("mono", "bayer", "bayer_640x480"),
        help="which speed cases to run",
    )
    ap.add_argument("--speed-only", action="store_true", help="the speed cases alone")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--speed-child", nargs=2, metavar=("NPY", "METHOD"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.speed_child:
        speed_child(*a.speed_child)
        return
    t0 = time.perf_counter()
    names = IMAGES[:3] if a.quick else IMAGES
    result: dict[str, Any] = {
        "bench": "mfsr",
        "conditions": {
            "cpus": os.cpu_count(),
            "load_avg_1m": round(os.getloadavg()[0], 2),
            "python": platform.python_version(),
            "opencv": cv2.__version__,
            "numpy": np.__version__,
            "noise_sigma": SIGMA,
            "frames": 16,
            "seed": a.seed,
            "images": list(names),
        },
    }
    if not a.speed_only:
        result.update(quality_parts(names, a.seed, blur=not a.no_blur))
    if not a.no_speed:
        result["speed"] = speed(a.seed, tuple(a.speed))
    result["bench_seconds"] = round(time.perf_counter() - t0, 1)
    print(json.dumps(result, sort_keys=True))


def quality_parts(names: tuple[str, ...], seed: int, *, blur: bool) -> dict[str, Any]:
    """Every quality figure: blur-free, Bayer and (``blur``) through a lens."""
    makers: dict[str, Maker] = {n: image_maker(n) for n in names}
    makers["simulator"] = simulator_maker()
    per = quality(makers, seed)
    out: dict[str, Any] = {"summary": summarise(per), "per_image": per}
    bq = bayer_quality(seed)
    out["bayer_summary"] = summarise_bayer(bq)
    out["bayer_per_image"] = bq
    if blur:
        bl = blurred(makers, seed)
        out["blurred_summary"] = summarise_blurred(bl)
        out["blurred_per_image"] = bl
        fv = field_varying(names, seed)
        out["field_varying_summary"] = summarise_field_varying(fv)
        out["field_varying_per_image"] = fv
    return out


if __name__ == "__main__":
    main()
