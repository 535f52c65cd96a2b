"""DSI and ML_DATA files: round trips and the layout they pin."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import tifffile

from elphel_host.tp import dsi
from elphel_host.tp.geometry import QuadGeometry


def test_dsi_round_trip(tmp_path: Path) -> None:
    layers = {
        "disparity": np.arange(12, dtype=np.float32).reshape(3, 4),
        "strength": np.ones((3, 4)),
    }
    path = tmp_path / "dsi.tif"
    dsi.write_dsi(path, layers, image_size=(32, 24), geometry=QuadGeometry(), bayer="GRBG")
    back, props = dsi.read_dsi(path)
    assert list(back) == ["disparity", "strength"]
    assert np.array_equal(back["disparity"], layers["disparity"])
    assert props["tileSize"] == "16" and props["tileStride"] == "8" and props["bayer"] == "GRBG"
    assert json.loads(props["cameraPositions"])[1] == [0.5, -0.5]
    with tifffile.TiffFile(path) as tif:
        assert tif.is_imagej and tif.pages[0].dtype == np.float32


def test_ml_data_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    corr = rng.random((3, 5, 6, 15, 15)).astype(np.float32)
    target = rng.random((3, 5)).astype(np.float32)
    truth = rng.random((3, 5)).astype(np.float32)
    path = tmp_path / dsi.ml_data_name("1526905735_662795", fat_zero=0.05)
    assert path.name == "1526905735_662795-ML_DATA-32B-O-FZ0.05-OFFS0.tiff"
    dsi.write_ml_data(path, corr, target, ground_truth=truth, combine_offset=-1)
    tiles, other, props = dsi.read_ml_data(path)
    assert tiles.shape == (3, 5, 9, 9, 4)
    assert np.allclose(tiles[..., 0], corr[:, :, 4, 3:12, 3:12])  # diagm-pair
    assert np.allclose(tiles[..., 2], 0.5 * (corr[:, :, 0, 3:12, 3:12] + corr[:, :, 1, 3:12, 3:12]))
    assert np.allclose(other[..., 0], target) and np.allclose(other[..., 1], truth)
    assert np.isnan(other[..., 2]).all()
    assert props["VERSION"] == "1.1"
