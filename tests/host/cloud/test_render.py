"""Pictures of clouds and distance histograms: depth colours, axes, outliers counted."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from elphel_host.cloud.ply import PointCloud
from elphel_host.cloud.render import (
    cloud_caption,
    cloud_picture,
    histogram_caption,
    histogram_png,
    histogram_range_mm,
    length_unit,
)
from elphel_host.preview import colour_map


def _two_planes() -> PointCloud:
    """A near plane (z 1000 mm) left, a far one (z 3000 mm) right, 20 far noise points."""
    g = np.linspace(-200.0, 200.0, 41)
    x, y = np.meshgrid(g, g)
    near = np.stack([x.ravel() - 300, y.ravel(), np.full(x.size, 1000.0)], axis=1)
    far = np.stack([x.ravel() + 300, y.ravel(), np.full(x.size, 3000.0)], axis=1)
    noise = np.stack([np.zeros(20), np.zeros(20), np.linspace(1e6, 2e8, 20)], axis=1)
    grey = np.full((2 * x.size + 20, 3), 128, np.uint8)
    return PointCloud(np.concatenate([near, far, noise]).astype(np.float32), rgb=grey)


def test_cloud_picture_colours_points_by_depth() -> None:
    picture = cloud_picture(_two_planes(), far_mm=10_000.0, title="cloud")
    pixels = picture.reshape(-1, 3)
    near_rgb, far_rgb = colour_map(np.array([1000.0, 3000.0]), 1000.0, 3000.0)

    def count(rgb: np.ndarray) -> int:
        return int((pixels == rgb).all(axis=1).sum())

    # the points are painted in the depth map's colours (both views), not their own grey
    assert count(near_rgb) > 1000 and count(far_rgb) > 1000
    assert count(np.array([128, 128, 128])) < 100  # (anti-aliased text has a few)
    assert picture.shape[1] > 2 * 360  # two views side by side


def test_cloud_caption_states_what_is_drawn() -> None:
    text = cloud_caption(1702, 1682, far=20, far_mm=1_227_273.0, title="MFSR cloud")
    assert text == (
        "MFSR cloud: 1682 of 1702 points drawn, coloured by depth z; "
        "20 far points (beyond 1227 m) left out"
    )
    assert length_unit(9_000.0) == ("mm", 1.0) and length_unit(12_000.0) == ("m", 1000.0)


def test_histogram_counts_what_it_leaves_out_and_keeps_its_labels(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    d = np.concatenate([np.abs(rng.normal(0, 800, 19_000)), rng.uniform(1e4, 4.3e6, 200)])
    hi = histogram_range_mm(d)
    assert 3_000 < hi < 5_000  # the bulk, not the outliers up to 4.3e6 mm
    assert histogram_caption(d, hi, title="a -> b") == (
        f"a -> b: 19200 points, 200 beyond {hi:.0f} mm not shown"
    )
    path = histogram_png(tmp_path / "h.png", d, title="a -> b")
    with Image.open(path) as im:
        picture = np.asarray(im.convert("RGB"))
    # nothing is drawn in the last columns: no tick label runs off the right edge
    assert (picture[:, -8:] == 255).all()
    # the bars fill the plot's width, not only its first bin
    row = picture[-60, 70:-40]
    assert (row != 255).any(axis=1).mean() > 0.3
