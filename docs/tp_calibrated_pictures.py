"""Regenerate the picture of docs/calibration.md (docs/img/tp-calibrated.png).

    elphel-sim calib-views views --views 20 --width 640 --height 480
    elphel calibrate solve views --pattern checkerboard:9x6:25 --out calib
    elphel-sim calib-scene raw --calibration calib --rectified rect --width 640 --height 480
    .venv/bin/python docs/tp_calibrated_pictures.py raw rect [--out docs/img]

Three DSIs of one scene on one colour scale: the rectified quad (ideal cameras), the raw
quad with its calibration, the same raw images read as an ideal quad (quad.json's
calibration left out); each title gives the RMS error against the simulator's truth
(``truth.json``) on the textured tiles inside one plane.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from PIL import Image

from elphel_host.preview import BACKGROUND_RGB, map_picture, save_png
from elphel_host.tp.geometry import QuadGeometry
from elphel_host.tp.images import QuadImages
from elphel_host.tp.io import read_quad_dir
from elphel_host.tp.processor import disparity_map


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("raw", type=Path, help="calib-scene's quad directory (with calibration)")
    ap.add_argument("rectified", type=Path, help="calib-scene's --rectified directory")
    ap.add_argument("--out", type=Path, default=Path("docs/img"))
    args = ap.parse_args()
    truth = json.loads((args.raw / "truth.json").read_text())
    true = np.array(truth["disparity"])
    scored = np.array(truth["interior"]) & np.array(truth["textured"])
    raw = read_quad_dir(args.raw).quad
    plain = QuadImages(raw.images, bayer=raw.bayer, geometry=QuadGeometry(raw.geometry.positions))
    quads = (
        ("rectified quad", read_quad_dir(args.rectified).quad),
        ("raw images + calibration", raw),
        ("raw images, no calibration", plain),
    )
    panels = []
    for name, quad in quads:
        d = disparity_map(quad)["disparity"]
        err = float(np.sqrt(np.mean((d - true)[scored] ** 2)))
        title = f"{name}: RMS error {err:.3f} px"
        panels.append(Image.fromarray(map_picture(d, unit="px", title=title, lo=-0.5, hi=5.5)))
    gap = 12
    sheet = Image.new(
        "RGB",
        (sum(p.width for p in panels) + gap * (len(panels) - 1), max(p.height for p in panels)),
        BACKGROUND_RGB,
    )
    x = 0
    for p in panels:
        sheet.paste(p, (x, 0))
        x += p.width + gap
    args.out.mkdir(parents=True, exist_ok=True)
    print(save_png(np.asarray(sheet), args.out / "tp-calibrated.png"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
