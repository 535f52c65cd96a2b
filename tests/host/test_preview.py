"""Pictures for people: demosaiced, white-balanced previews and maps with a colour bar."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from elphel_host.mfsr.output import write_image
from elphel_host.preview import (
    DISAGREE_RGB,
    FAR_RGB,
    NO_VALUE_RGB,
    Swatch,
    colour_map,
    demosaic,
    labelled_row,
    map_legend,
    map_picture,
    preview_rgb,
    robust_range,
    text_width,
)

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


def test_map_picture_has_a_colour_bar_and_a_no_value_colour() -> None:
    values = np.linspace(0, 6, 12 * 16).reshape(12, 16)
    values[0, :4] = np.nan
    picture = map_picture(values, lo=0.0, hi=6.0, unit="px", title="disparity", no_value="weak")
    assert picture.ndim == 3 and picture.shape[2] == 3
    top = 24  # title line
    body = picture[top : top + 12 * 8, 10 : 10 + 16 * 8]
    assert tuple(body[2, 2]) == NO_VALUE_RGB  # the NaN tiles
    bar = picture[top : top + 160, 10 + 16 * 8 + 10 + 9]  # the bar's middle column
    assert tuple(bar[2]) != tuple(bar[-3])  # hi at the top, lo at the bottom
    with pytest.raises(ValueError, match="hi > lo"):
        map_picture(values, lo=1.0, hi=1.0, unit="px", title="x")


def test_the_colours_of_missing_values_are_not_on_the_colour_map() -> None:
    ramp = colour_map(np.linspace(0.0, 1.0, 512), 0.0, 1.0).astype(float)
    for rgb in (NO_VALUE_RGB, FAR_RGB, DISAGREE_RGB):
        distance = np.sqrt(((ramp - np.array(rgb, float)) ** 2).sum(axis=1)).min()
        assert distance > 80, (rgb, distance)
        # light, so not taken for the map's dark end
        assert np.mean(rgb) > 150, rgb
    assert len({NO_VALUE_RGB, FAR_RGB, DISAGREE_RGB}) == 3


def test_labels_have_visible_spaces() -> None:
    # the legend once read "grey: nodepth" and a caption "MFSR19032 points"
    assert text_width("no depth") - text_width("nodepth") >= 3
    assert text_width("MFSR 19032") - text_width("MFSR19032") >= 3


def test_the_colour_bar_spans_the_robust_range() -> None:
    rng = np.random.default_rng(3)
    depth = rng.uniform(50_000, 150_000, (30, 40))
    depth[rng.random(depth.shape) < 0.01] = 2.7e8  # a few noise tiles kilometres away
    lo, hi = robust_range(depth)
    assert 50_000 <= lo < 55_000 and 145_000 < hi <= 150_000
    assert robust_range(np.full((3, 3), 2.0)) == (1.5, 2.5)
    assert robust_range(np.full((3, 3), np.nan)) == (0.0, 1.0)
    picture = map_picture(depth, unit="mm", title="depth", cell=4)
    body = picture[24 : 24 + 30 * 4, 10 : 10 + 40 * 4]
    # the bulk spreads over the map: dark purple to yellow, not one colour
    assert body.reshape(-1, 3).astype(int).std(axis=0).max() > 40


def test_swatches_paint_left_out_cells_and_name_them() -> None:
    values = np.linspace(0.0, 6.0, 10 * 12).reshape(10, 12)
    far = np.zeros(values.shape, bool)
    far[:2] = True
    weak = np.zeros(values.shape, bool)
    weak[-2:] = True
    values[-2:] = np.nan
    values[5, 5] = 1e6  # beyond the bar
    swatches = [Swatch("far: beyond 1 km", far, FAR_RGB), Swatch("no texture", weak, NO_VALUE_RGB)]
    picture = map_picture(values, unit="px", title="x", swatches=swatches, lo=0.0, hi=6.0)
    body = picture[24 : 24 + 80, 10 : 10 + 96]
    assert tuple(body[4, 4]) == FAR_RGB and tuple(body[-4, 4]) == NO_VALUE_RGB
    legend = map_legend(values, lo=0.0, hi=6.0, unit="px", swatches=swatches)
    assert legend[:2] == [(FAR_RGB, "far: beyond 1 km"), (NO_VALUE_RGB, "no texture")]
    assert legend[2] == (None, "0 below 0 px and 1 above 6 px shown in the bar's end colours")


def test_a_fused_rgb_image_is_balanced_like_a_frame(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    grey = rng.uniform(500, 3000, (64, 64))
    # a fused Bayer burst keeps the sensor's cast (the old fused.png: R 176, G 197, B 150)
    fused = np.stack([grey * 0.8, grey * 1.0, grey * 0.6], axis=-1).astype(np.float32)
    written = write_image(tmp_path / "fused.tif", fused, as_float=False, meta={})
    with Image.open(written["preview"]) as im:
        means = np.asarray(im, np.float64).reshape(-1, 3).mean(axis=0)
    assert np.all(np.abs(means / means[1] - 1) < 0.03), means
    frame = preview_rgb(fused[..., 1].astype(np.uint16), None).astype(np.float64)
    assert abs(frame.mean() - means.mean()) < 3  # one tone curve for both


def test_labelled_row_labels_each_panel_on_one_tone_scale() -> None:
    image = np.tile(np.linspace(100.0, 4000.0, 64), (48, 1))
    picture = labelled_row([("bicubic", image), ("baseline", image), ("robust", image)])
    label_h = 20
    assert picture.shape == (48 + label_h, 3 * 64 + 2 * 4, 3)
    for i in range(3):
        strip = picture[:label_h, i * 68 : i * 68 + 64]
        assert (strip < 100).any(), i  # its label's text
        assert (picture[label_h:, i * 68 : i * 68 + 64] == picture[label_h:, :64]).all()
    with pytest.raises(ValueError, match="allowed"):
        labelled_row([("a", image), ("b", image[:10])])
