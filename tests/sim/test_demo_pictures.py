"""The demo's quad pictures: one robust bar for DSI and truth, far and weak tiles named."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from elphel_host.preview import FAR_RGB, NO_VALUE_RGB
from elphel_sim.demo.run import save_quad_pictures

OPTICS = {"focal_length_mm": 4.5, "pixel_pitch_um": 2.2, "baseline_mm": 150.0}


def _tile(path: Path, ty: int, tx: int) -> tuple[int, ...]:
    with Image.open(path) as im:
        picture = np.asarray(im.convert("RGB"))
    return tuple(int(c) for c in picture[24 + 2 * ty + 1, 10 + 2 * tx + 1])


def test_demo_pictures_name_far_and_texture_less_tiles(tmp_path: Path) -> None:
    truth = np.zeros((40, 60))
    truth[5:20, 5:25] = 2.5  # a near plane on a background at infinity
    truth[25:35, 30:55] = 5.2
    rng = np.random.default_rng(0)
    disparity = truth + rng.normal(0, 0.03, truth.shape)
    strength = np.full(truth.shape, 0.4)
    strength[25:35, 45:55] = 0.05  # texture-less
    save_quad_pictures(tmp_path, disparity, strength, truth, OPTICS)
    assert _tile(tmp_path / "disparity.png", 30, 50) == NO_VALUE_RGB
    assert _tile(tmp_path / "depth.png", 30, 50) == NO_VALUE_RGB
    assert _tile(tmp_path / "depth.png", 2, 2) == FAR_RGB  # the background
    near, mid = _tile(tmp_path / "depth.png", 30, 35), _tile(tmp_path / "depth.png", 10, 10)
    assert near not in (FAR_RGB, NO_VALUE_RGB) and np.abs(np.subtract(near, mid)).sum() > 100
