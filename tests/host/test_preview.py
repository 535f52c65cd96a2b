"""Pictures for people: demosaiced, white-balanced previews and maps with a colour bar."""

from __future__ import annotations

import numpy as np
import pytest

from elphel_host.preview import NO_VALUE_RGB, demosaic, map_picture, preview_rgb

PATTERNS = ("RGGB", "GRBG", "GBRG", "BGGR")


def mosaic(rgb: np.ndarray, pattern: str) -> np.ndarray:
    """Sample an RGB scene (H, W, 3) through a Bayer pattern."""
    out = np.zeros(rgb.shape[:2], dtype=np.uint16)
    for k, (dy, dx) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
        out[dy::2, dx::2] = rgb[dy::2, dx::2, "RGB".index(pattern[k])]
    return out


@pytest.mark.parametrize("pattern", PATTERNS)
def test_demosaic_puts_each_colour_where_it_belongs(pattern: str) -> None:
    scene = np.zeros((16, 16, 3), dtype=np.uint16)
    scene[...] = (3000, 800, 200)
    rgb = demosaic(mosaic(scene, pattern), pattern)
    assert rgb.shape == (16, 16, 3)
    np.testing.assert_allclose(rgb[4:12, 4:12], np.broadcast_to((3000, 800, 200), (8, 8, 3)))


def test_a_grey_scene_under_a_green_cast_comes_out_grey() -> None:
    rng = np.random.default_rng(1)
    grey = rng.uniform(500, 3000, (64, 64))
    # The sensor sees green twice as strongly (no white balance): the old preview was green.
    scene = np.stack([grey * 0.6, grey * 1.2, grey * 0.45], axis=-1).astype(np.uint16)
    picture = preview_rgb(mosaic(scene, "GRBG"), "GRBG").astype(np.float64)
    means = picture[8:-8, 8:-8].reshape(-1, 3).mean(axis=0)
    assert np.all(np.abs(means / means[1] - 1) < 0.03), means


def test_the_mosaic_view_is_the_raw_frame_pixel_for_pixel() -> None:
    frame = np.arange(24 * 32, dtype=np.uint16).reshape(24, 32) * 5
    grey = preview_rgb(frame, "GRBG", mosaic=True)
    assert grey.shape == (24, 32) and grey.dtype == np.uint8
    assert np.all(np.diff(grey.astype(int).ravel()) >= 0)  # monotone in the raw values


def test_map_picture_has_a_colour_bar_and_grey_for_no_value() -> None:
    values = np.linspace(0, 6, 12 * 16).reshape(12, 16)
    values[0, :4] = np.nan
    picture = map_picture(values, lo=0.0, hi=6.0, unit="px", title="disparity", no_value="weak")
    assert picture.ndim == 3 and picture.shape[2] == 3
    body = picture[24 : 24 + 12 * 8, 10 : 10 + 16 * 8]
    assert tuple(body[2, 2]) == NO_VALUE_RGB  # the NaN tiles
    bar = picture[24 : 24 + 160, 10 + 16 * 8 + 10 + 9]  # the bar's middle column
    assert tuple(bar[2]) != tuple(bar[-3])  # hi at the top, lo at the bottom
    with pytest.raises(ValueError, match="hi > lo"):
        map_picture(values, lo=1.0, hi=1.0, unit="px", title="x")
