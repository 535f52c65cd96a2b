"""Regenerate the pictures of docs/mfsr.md (docs/img/mfsr-*.png).

    make demo                                  # writes out/mfsr-compare and the reference
    .venv/bin/python docs/mfsr_pictures.py [--demo-out out] [--out docs/img]

* ``mfsr-demo-x2.png``: the demo burst (simulated MT9P006, Bayer, x2), centre crops of
  bicubic | baseline | robust | the simulator's reference, from ``out/``.
* ``mfsr-camera-x2.png``, ``mfsr-text-x4.png``: bursts of the synthetic benchmark
  (bench/mfsr.py: same images, noise, seeds and shifts, so the same scores), x2 and x4.

Every panel of a picture shares one tone scale (the reference's) and is enlarged with
nearest neighbours; each label gives PSNR/SSIM against the reference as the bench and
``elphel mfsr compare`` compute them.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
import skimage.data

from elphel_host.mfsr.fuse import fuse_frames
from elphel_host.mfsr.metrics import psnr, ssim
from elphel_host.mfsr.synth import make_burst, random_shifts
from elphel_sim.demo.report import burst_crops, comparison_picture

# bench/mfsr.py: IMAGES order, seed, noise
BENCH_IMAGES = ("camera", "astronaut", "brick", "text", "coins", "moon")
BENCH_SEED = 2026
BENCH_SIGMA = 0.01


def synthetic(
    name: str, scale: int, out: Path, *, centre: tuple[int, int], size: int, zoom: int
) -> Path:
    img = getattr(skimage.data, name)()
    if img.ndim == 3:
        img = img.mean(axis=2)
    hr = (np.asarray(img, np.float32) / 255.0).astype(np.float32)
    hr = hr[: hr.shape[0] // scale * scale, : hr.shape[1] // scale * scale]
    n = BENCH_IMAGES.index(name)
    shifts = random_shifts(16, seed=BENCH_SEED + n, spread=2.0)
    frames = make_burst(hr, shifts, scale=scale, noise_sigma=BENCH_SIGMA, seed=BENCH_SEED + 100 + n)
    methods = ("bicubic", "baseline", "robust") if scale == 2 else ("bicubic", "robust")
    panels: list[tuple[str, Any]] = []
    for m in methods:
        image = fuse_frames(frames, scale=scale, method=m).image
        p = psnr(hr, image, data_range=1.0, border=4 * scale)
        s = ssim(hr, image, data_range=1.0, border=4 * scale)
        panels.append((f"{m} {p:.2f} dB, SSIM {s:.3f}", image))
    panels.append((f"{name} (truth)", hr))
    return comparison_picture(panels, out, size=size, zoom=zoom, centre=centre)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demo-out", type=Path, default=Path("out"), help="`make demo` output")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "img")
    a = ap.parse_args()
    written = [
        burst_crops(
            a.demo_out / "mfsr-compare",
            a.demo_out / "burst-reference.tif",
            a.out / "mfsr-demo-x2.png",
        ),
        synthetic("camera", 2, a.out / "mfsr-camera-x2.png", centre=(150, 250), size=96, zoom=3),
        synthetic("text", 4, a.out / "mfsr-text-x4.png", centre=(86, 190), size=144, zoom=2),
    ]
    print(json.dumps({str(p): p.stat().st_size for p in written}))


if __name__ == "__main__":
    main()
