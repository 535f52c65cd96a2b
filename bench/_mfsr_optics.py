"""The MFSR benchmark's bursts through a lens (a module of bench/mfsr.py, not a benchmark).

Two sets, x2, 16 frames, random 2-D offsets, noise sigma 0.01, no method told the blur:

- `blurred`: the benchmark's scenes through one Gaussian optics blur of sigma 0.5, 0.7 or
  1.0 HR px (before the pixel integration), scored against the sharp HR image; besides
  the methods told nothing, the robust method given the true blur (a calibrated lens),
  with its prior's tau cross-validated (the default) and at the fixed 0.04.
- `field_varying`: the six photographs through a blur that grows with the squared
  distance from the centre, 0.4 HR px there to 1.2 HR px at the corners (the simulator's
  ``--lens-blur C:E`` model: the image blurred at five sigmas spanning the range,
  interpolated per pixel). The default (one PSF estimated for the frame) against the
  lens's own PSFs given per region (a calibration: 3x3 regions, fewer on the coins and
  the text, each cell the Gaussian of the model's sigma at its centre, as a 4-D PSF file
  would give it). PSNR over the frame and over its outer field (where the blur is 1.0 HR
  px or more).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from elphel_host.mfsr.fuse import fuse_frames
from elphel_host.mfsr.gaussian_psf import GaussianPsf
from elphel_host.mfsr.metrics import psnr, ssim
from elphel_host.mfsr.psf_spec import GivenGrid, NoBlur
from elphel_host.mfsr.robust_config import RobustConfig
from elphel_host.mfsr.synth import make_burst, random_shifts

SIGMA = 0.01
BLURS = (0.5, 0.7, 1.0)
NO_PSF = RobustConfig(psf=NoBlur())
#: The field-varying lens: sigma (HR px) on the axis and at the corners, and its levels.
FIELD_BLUR = (0.4, 1.2)
FIELD_LEVELS = 5
#: Regions a side, fewer where the image is too small for cells of 64 LR px (the text).
FIELD_REGIONS = 3

# (shifts, scale, seed, optics blur sigma in HR px) -> (frames, sharp HR truth)
Maker = Callable[..., tuple[list[np.ndarray], np.ndarray]]


def load(name: str) -> np.ndarray:
    import skimage.data as sd

    img = getattr(sd, name)()
    if img.ndim == 3:
        img = img.mean(axis=2)
    return (np.asarray(img, np.float32) / 255.0).astype(np.float32)


def crop_to(img: np.ndarray, s: int) -> np.ndarray:
    return img[: img.shape[0] // s * s, : img.shape[1] // s * s]


def gaussian_blur(img: np.ndarray, sigma: float) -> np.ndarray:
    if sigma <= 0:
        return img
    out = cv2.GaussianBlur(img, (0, 0), sigma, borderType=cv2.BORDER_REFLECT_101)
    return np.asarray(out, np.float32)


def mean_db(xs: list[float]) -> float:
    return round(float(np.mean(xs)), 3)


def blurred(makers: dict[str, Maker], seed: int) -> dict[str, Any]:
    """x2, 16 frames, random 2-D offsets, optics blur unknown to the methods."""
    per: dict[str, Any] = {}
    for n_img, (name, make) in enumerate(makers.items()):
        row: dict[str, Any] = {}
        for blur in BLURS:
            shifts = random_shifts(16, seed=seed + n_img, spread=2.0)
            frames, hr = make(shifts, 2, seed + 100 + n_img, blur)
            rng_ = float(hr.max() - hr.min()) if name == "simulator" else 1.0
            res = {m: fuse_frames(frames, scale=2, method=m) for m in ("bicubic", "baseline")}
            res["robust"] = fuse_frames(frames, scale=2, method="robust")
            res["robust_no_psf"] = fuse_frames(frames, scale=2, method="robust", config=NO_PSF)
            # a calibrated lens: the true blur given, its prior's tau cross-validated or not
            for m, cfg in (
                ("robust_given", RobustConfig(psf=GaussianPsf.round(blur))),
                (
                    "robust_given_fixed_tau",
                    RobustConfig(psf=GaussianPsf.round(blur), choose_tau=False),
                ),
            ):
                res[m] = fuse_frames(frames, scale=2, method="robust", config=cfg)
            r: dict[str, Any] = {
                m: {
                    "psnr_db": round(psnr(hr, v.image, data_range=rng_, border=8), 3),
                    "ssim": round(ssim(hr, v.image, data_range=rng_, border=8), 4),
                }
                for m, v in res.items()
            }
            psf = res["robust"].info["psf"]
            r["psf"] = psf
            r["psf_sigma_error_hr_px"] = round(psf["sigma_hr_px"] - blur, 4)
            r["apparent_sigma_error_hr_px"] = round(psf["apparent_sigma_hr_px"] - blur, 4)
            row[f"sigma_{blur}"] = r
        per[name] = row
    return per


def summarise_blurred(per: dict[str, Any]) -> dict[str, Any]:
    def gains(a: str, b: str, blur: float | None = None) -> list[float]:
        return [
            v[k][a]["psnr_db"] - v[k][b]["psnr_db"]
            for v in per.values()
            for k in v
            if blur is None or k == f"sigma_{blur}"
        ]

    def errors(key: str) -> dict[str, Any]:
        e = [abs(v[k][key]) for v in per.values() for k in v]
        return {
            "abs_mean": round(float(np.mean(e)), 4),
            "abs_max": round(float(np.max(e)), 4),
            "within_0.1_px": f"{sum(x <= 0.1 for x in e)}/{len(e)}",
        }

    out: dict[str, Any] = {
        "robust_gain_over_bicubic_db_mean": mean_db(gains("robust", "bicubic")),
        "robust_gain_over_baseline_db_mean": mean_db(gains("robust", "baseline")),
        "robust_gain_over_baseline_db_min": round(float(np.min(gains("robust", "baseline"))), 3),
        "robust_no_psf_gain_over_bicubic_db_mean": mean_db(gains("robust_no_psf", "bicubic")),
        "robust_gain_over_no_psf_db_mean": mean_db(gains("robust", "robust_no_psf")),
        "robust_given_gain_over_bicubic_db_mean": mean_db(gains("robust_given", "bicubic")),
        "robust_given_minus_robust_db_mean": mean_db(gains("robust_given", "robust")),
        "robust_given_minus_fixed_tau_db_mean": mean_db(
            gains("robust_given", "robust_given_fixed_tau")
        ),
        "robust_given_minus_fixed_tau_db_min": round(
            float(np.min(gains("robust_given", "robust_given_fixed_tau"))), 3
        ),
        "psf_sigma_error_hr_px": errors("psf_sigma_error_hr_px"),
        "apparent_sigma_error_hr_px": errors("apparent_sigma_error_hr_px"),
    }
    for blur in BLURS:
        out[f"sigma_{blur}"] = {
            "robust_gain_over_bicubic_db_mean": mean_db(gains("robust", "bicubic", blur)),
            "robust_gain_over_baseline_db_mean": mean_db(gains("robust", "baseline", blur)),
            "robust_gain_over_baseline_db_min": round(
                float(np.min(gains("robust", "baseline", blur))), 3
            ),
            "robust_no_psf_gain_over_bicubic_db_mean": mean_db(
                gains("robust_no_psf", "bicubic", blur)
            ),
        }
    return out


def field_sigma(shape: tuple[int, int], ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """The field-varying lens's sigma (HR px) at pixel centres (rows ``ys``, columns ``xs``)."""
    h, w = shape
    r2 = ((ys + 0.5 - h / 2) ** 2 + (xs + 0.5 - w / 2) ** 2) / ((h / 2) ** 2 + (w / 2) ** 2)
    centre, corner = FIELD_BLUR
    return np.asarray(centre + (corner - centre) * r2)


def field_sigma_map(shape: tuple[int, int]) -> np.ndarray:
    """The field-varying lens's sigma (HR px) at every pixel of an image of ``shape``."""
    return field_sigma(shape, np.arange(shape[0])[:, None], np.arange(shape[1])[None, :])


def field_blur(img: np.ndarray, sig: np.ndarray) -> np.ndarray:
    """``img`` through the lens of sigmas ``sig`` (hat-weighted levels, as the simulator's)."""
    lo, hi = FIELD_BLUR
    pos = (sig - lo) / (hi - lo) * (FIELD_LEVELS - 1)
    out = np.zeros(img.shape, np.float64)
    for k, s in enumerate(np.linspace(lo, hi, FIELD_LEVELS)):
        out += gaussian_blur(img, float(s)) * np.clip(1.0 - np.abs(pos - k), 0.0, 1.0)
    return out.astype(np.float32)


def field_regions(shape: tuple[int, int], scale: int = 2) -> tuple[int, int]:
    """Up to 3x3 regions of at least 64 LR px a side on an HR image of ``shape``."""
    return (
        min(FIELD_REGIONS, shape[0] // scale // 64),
        min(FIELD_REGIONS, shape[1] // scale // 64),
    )


def field_psf_grid(shape: tuple[int, int], radius: int = 5) -> np.ndarray:
    """The lens's Gaussians at the centres of the regions, as a 4-D PSF file holds them."""
    (ky, kx), (h, w) = field_regions(shape), shape
    d = np.arange(-radius, radius + 1, dtype=np.float64)
    grid = np.zeros((ky, kx, d.size, d.size))
    for iy in range(ky):
        for ix in range(kx):
            s = float(
                field_sigma(shape, np.array((iy + 0.5) * h / ky), np.array((ix + 0.5) * w / kx))
            )
            g = np.exp(-0.5 * (d / s) ** 2)
            grid[iy, ix] = np.outer(g, g) / np.outer(g, g).sum()
    return grid


def field_varying(names: tuple[str, ...], seed: int) -> dict[str, Any]:
    """The photographs through the field-varying lens: one PSF estimated, or given per region."""
    per: dict[str, Any] = {}
    for n_img, name in enumerate(names):
        hr = crop_to(load(name), 2)
        sig, regions = field_sigma_map(hr.shape), field_regions(hr.shape)
        shifts = random_shifts(16, seed=seed + n_img, spread=2.0)
        frames = make_burst(
            field_blur(hr, sig), shifts, scale=2, noise_sigma=SIGMA, seed=seed + 300 + n_img
        )
        configs = {
            "robust": RobustConfig(),
            "robust_regions_given": RobustConfig(psf=GivenGrid(field_psf_grid(hr.shape))),
        }
        res = {m: fuse_frames(frames, scale=2, method=m) for m in ("bicubic", "baseline")}
        for m, cfg in configs.items():
            res[m] = fuse_frames(frames, scale=2, method="robust", config=cfg)
        outer = sig >= 1.0
        inside = np.zeros_like(outer)
        inside[8:-8, 8:-8] = True
        row: dict[str, Any] = {"regions": list(regions)}
        for m, v in res.items():
            err = (v.image - hr)[outer & inside].astype(np.float64)
            row[m] = {
                "psnr_db": round(psnr(hr, v.image, data_range=1.0, border=8), 3),
                "outer_psnr_db": round(float(-10 * np.log10(np.mean(err * err))), 3),
            }
        row["one_psf_apparent_sigma_hr_px"] = res["robust"].info["psf"]["apparent_sigma_hr_px"]
        per[name] = row
    return per


def summarise_field_varying(per: dict[str, Any]) -> dict[str, Any]:
    def gains(a: str, b: str, key: str = "psnr_db") -> list[float]:
        return [v[a][key] - v[b][key] for v in per.values()]

    out: dict[str, Any] = {"lens_sigma_hr_px": {"centre": FIELD_BLUR[0], "corner": FIELD_BLUR[1]}}
    for m in ("robust", "robust_regions_given"):
        out[f"{m}_gain_over_bicubic_db_mean"] = mean_db(gains(m, "bicubic"))
        out[f"{m}_gain_over_baseline_db_min"] = round(float(np.min(gains(m, "baseline"))), 3)
    for m in ("robust_regions_given",):
        out[f"{m}_minus_robust_db_mean"] = mean_db(gains(m, "robust"))
        out[f"{m}_minus_robust_db_min"] = round(float(np.min(gains(m, "robust"))), 3)
        out[f"{m}_minus_robust_outer_db_mean"] = mean_db(gains(m, "robust", "outer_psnr_db"))
    return out
