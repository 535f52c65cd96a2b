"""JP4 benchmark: decoding a 2592x1936 frame to linear 16-bit vs a plain decode, and convert.

Encodes a seeded 12-bit Bayer frame (smooth + texture over the whole range) as the
simulated NC393 does (JP4, gamma 0.57, black 10/256), then in the same run:
- decodes it with `decode_jp4` (JPEG decode + block layout + gamma undone per site) and
  with a plain Pillow decode of the same JPEG to an 8-bit array, alternating, best of N;
- states the round-trip error at quality 100 and 90 in 8-bit code steps and DN;
- converts FILES such frames with `elphel_host.recordings.convert` on one thread and on
  every core, reporting wall time, CPU time and CPU/wall.
Prints exactly one JSON object.

    .venv/bin/python bench/jp4.py [--files 100 --repeat 15 --workers 2]
"""

from __future__ import annotations

import argparse
import io
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import PIL
from PIL import Image, features

from elphel_host.camera.jp4 import decode_jp4
from elphel_host.parallel import THREADS
from elphel_host.recordings import convert
from elphel_sim.jp4 import code_lut, encode_jp4, gamma_table

WIDTH, HEIGHT = 2592, 1936
GAMMA, BLACK = 0.57, 10 / 256
T0 = 1_700_000_000


def source(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH] / np.array([HEIGHT, WIDTH]).reshape(2, 1, 1)
    base = 0.5 + 0.5 * np.sin(2 * np.pi * (6.3 * x + 2.4 * y)) * np.cos(2 * np.pi * 3.7 * y)
    value = np.clip(base + rng.normal(0.0, 0.04, (HEIGHT, WIDTH)), 0.0, 1.0)
    level = np.tile(np.array([[0.8, 1.0], [0.45, 0.8]]), (HEIGHT // 2, WIDTH // 2))
    return np.round(value * level * 4095).astype(np.uint16)


def plain_decode(data: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(data)) as im:
        im.load()
        return np.asarray(im)


def timed(fn: Any) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def errors(mosaic: np.ndarray, quality: int) -> dict[str, float]:
    """Decoded vs source, in the camera's 8-bit code steps at each pixel's level and in DN."""
    data = encode_jp4(mosaic, bits=12, frame=1, timestamp_ns=T0 * 10**9, quality=quality,
                      gamma=GAMMA, black=BLACK)  # fmt: skip
    image, _ = decode_jp4(data)
    lut = code_lut(gamma_table(GAMMA, BLACK, 0x400))
    v = np.arange(65536)
    lo, hi = np.full(256, 65536.0), np.zeros(256)
    np.minimum.at(lo, lut, v)
    np.maximum.at(hi, lut, v + 1)
    step = (hi - lo) / 65536 * 65535
    code = lut[mosaic.astype(np.int64) * 16]
    error = np.abs(image - np.clip((mosaic * 16.0 / 65536 - BLACK) * 65535, 0, None))
    steps = error / step[code]
    return {
        "median_code_steps": round(float(np.median(steps)), 3),
        "p99_code_steps": round(float(np.percentile(steps, 99)), 2),
        "max_code_steps": round(float(steps.max()), 2),
        "rms_dn_of_65535": round(float(np.sqrt(np.mean(error**2))), 1),
        "file_bytes": len(data),
    }


def run_convert(files: list[Path], out: Path, workers: int) -> dict[str, float]:
    shutil.rmtree(out, ignore_errors=True)
    wall, cpu = time.perf_counter(), time.process_time()
    result = convert(files, out, workers=workers)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    if result.failed or len(result.converted) != len(files):
        raise SystemExit(f"convert failed: {result.failed[:1]}")
    shutil.rmtree(out, ignore_errors=True)
    return {
        "workers": workers,
        "wall_s": round(wall, 3),
        "cpu_s": round(cpu, 3),
        "cpu_over_wall": round(cpu / wall, 3),
        "frames_per_s": round(len(files) / wall, 2),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--files", type=int, default=100)
    ap.add_argument("--repeat", type=int, default=15, help="decode timing runs (best reported)")
    ap.add_argument("--workers", type=int, default=THREADS)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    mosaic = source(args.seed)
    data = encode_jp4(mosaic, bits=12, frame=1, timestamp_ns=T0 * 10**9, quality=100,
                      gamma=GAMMA, black=BLACK)  # fmt: skip
    load_before = os.getloadavg()[0]
    plain_decode(data), decode_jp4(data)  # warm: caches, tables
    plain, full = [], []
    for _ in range(args.repeat):
        plain.append(timed(lambda: plain_decode(data)))
        full.append(timed(lambda: decode_jp4(data)))
    plain_s, full_s = min(plain), min(full)

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        variants = [
            encode_jp4(
                source(args.seed + k),
                bits=12,
                frame=k,
                timestamp_ns=(T0 + k) * 10**9,
                quality=100,
                gamma=GAMMA,
                black=BLACK,
            )
            for k in range(4)
        ]
        files = []
        for k in range(args.files):
            path = root / "rec" / f"{T0 + k}_000000_{k % 4}.jp4"
            path.parent.mkdir(exist_ok=True)
            path.write_bytes(variants[k % 4])
            files.append(path)
        one = run_convert(files, root / "out", 1)
        every = run_convert(files, root / "out", args.workers)

    result: dict[str, Any] = {
        "conditions": {
            "cpus": os.cpu_count(),
            "load_average_1min_before": load_before,
            "python": sys.version.split()[0],
            "numpy": np.__version__,
            "pillow": PIL.__version__,
            "libjpeg_turbo": features.check_feature("libjpeg_turbo"),
            "libjpeg_version": features.version("jpg"),
            "machine": platform.machine(),
            "width": WIDTH,
            "height": HEIGHT,
            "jpeg_bytes": len(data),
            "quality": 100,
            "gamma": GAMMA,
            "black": BLACK,
            "decode_runs": args.repeat,
        },
        "decode": {
            "plain_pillow_s": round(plain_s, 4),
            "decode_jp4_s": round(full_s, 4),
            "plain_median_s": round(float(np.median(plain)), 4),
            "decode_jp4_median_s": round(float(np.median(full)), 4),
        },
        "round_trip": {"quality_100": errors(mosaic, 100), "quality_90": errors(mosaic, 90)},
        "convert": {"files": args.files, "one_worker": one, "every_core": every},
    }
    ratios = {
        "decode_jp4_over_plain": round(full_s / plain_s, 3),
        "decode_jp4_over_plain_median": round(float(np.median(full) / np.median(plain)), 3),
        "convert_speedup": round(one["wall_s"] / every["wall_s"], 3),
        "cpu_over_wall_every_core_over_one": round(
            every["cpu_over_wall"] / one["cpu_over_wall"], 3
        ),
    }
    result["ratios"] = ratios
    result["targets_met"] = {
        "decode_le_1.5x_plain": ratios["decode_jp4_over_plain"] <= 1.5,
        "convert_uses_both_cores": every["cpu_over_wall"] >= 1.5,
        "quality_100_median_under_half_step": (
            result["round_trip"]["quality_100"]["median_code_steps"] < 0.5
        ),
    }
    print(json.dumps(result, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
