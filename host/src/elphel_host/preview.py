"""8-bit pictures for people to look at: frame previews and maps with a colour bar.

A Bayer frame is demosaiced at full resolution (OpenCV's bilinear demosaic) and
white-balanced (grey world: each colour scaled so its mean over the mid-tones equals
green's), then stretched to 8 bits with a display gamma; ``mosaic=True`` shows the raw
mosaic as grey instead, pixel for pixel. `map_picture` colours a tile map (disparity in
px, depth in mm) and draws a colour bar in its unit and a legend for the tiles that have
no value (texture-less or weak).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from PIL import Image, ImageDraw

# OpenCV names a Bayer pattern by the second row's second and third pixels, not the first
# row's: a GRBG sensor is cv2's "GB" (checked on all four by tests/host/test_preview.py).
_CV_BAYER = {"RGGB": "BG", "GRBG": "GB", "GBRG": "GR", "BGGR": "RG"}
# dark blue -> blue -> green -> yellow -> red (RGB)
_ANCHORS = np.array(
    [[48, 18, 59], [31, 120, 180], [32, 178, 120], [240, 200, 40], [220, 50, 30]],
    dtype=np.float64,
)
NO_VALUE_RGB = (90, 90, 90)


def _stretch(a: NDArray[np.float64]) -> NDArray[np.uint8]:
    lo, hi = np.percentile(a, [0.5, 99.5])
    scaled = (a - lo) / max(hi - lo, 1e-12)
    out: NDArray[np.uint8] = (np.clip(scaled, 0, 1) ** (1 / 2.2) * 255 + 0.5).astype(np.uint8)
    return out


def demosaic(image: NDArray[Any], bayer: str) -> NDArray[np.float64]:
    """Full-resolution RGB (H, W, 3) of a Bayer mosaic ``bayer`` ("GRBG", ...).

    Raises
    ------
    ValueError
        An unknown pattern or an image that is not 2-D.
    """
    import cv2

    a = np.asarray(image)
    if a.ndim != 2:
        raise ValueError(f"a Bayer mosaic is 2-D; got shape {a.shape}")
    code = _CV_BAYER.get(bayer.upper())
    if code is None:
        raise ValueError(f"Bayer pattern {bayer!r}; allowed: {', '.join(_CV_BAYER)}")
    h, w = (a.shape[0] // 2) * 2, (a.shape[1] // 2) * 2
    mosaic = np.ascontiguousarray(a[:h, :w].astype(np.uint16))
    rgb = cv2.cvtColor(mosaic, getattr(cv2, f"COLOR_Bayer{code}2RGB"))
    return np.asarray(rgb, dtype=np.float64)


def white_balance(rgb: NDArray[np.float64]) -> NDArray[np.float64]:
    """Grey world on the mid-tones: scale R and B so their means equal G's.

    Pixels in the top 1% of brightness (highlights, clipped areas) and the darkest 1% are
    left out of the means, so a few saturated pixels do not tint the picture.
    """
    luma = rgb.mean(axis=-1)
    lo, hi = np.percentile(luma, [1, 99])
    mid = (luma >= lo) & (luma <= hi)
    if not mid.any():
        return rgb
    means = rgb[mid].mean(axis=0)
    gains = means[1] / np.maximum(means, 1e-12)
    return rgb * gains


def preview_rgb(
    image: NDArray[Any], bayer: str | None, *, mosaic: bool = False
) -> NDArray[np.uint8]:
    """An 8-bit picture of a raw frame: RGB demosaiced and white-balanced, or grey.

    Parameters
    ----------
    image
        The raw frame (H, W), any integer or float type.
    bayer
        Its mosaic ("GRBG", ...), or None for a mono sensor (grey).
    mosaic
        Show the raw mosaic as grey, pixel for pixel, instead of colour.
    """
    a = np.asarray(image, dtype=np.float64)
    if bayer is None or mosaic:
        return _stretch(a)
    return _stretch(white_balance(demosaic(image, bayer)))


def save_preview(
    image: NDArray[Any], path: str | Path, *, bayer: str | None = None, mosaic: bool = False
) -> Path:
    """Write a PNG preview of a raw frame (see `preview_rgb`) and return its path."""
    path = Path(path)
    Image.fromarray(preview_rgb(image, bayer, mosaic=mosaic)).save(path)
    return path


def colour_map(values: NDArray[np.floating], lo: float, hi: float) -> NDArray[np.uint8]:
    """Map values to RGB along a dark-blue -> green -> yellow -> red ramp; NaN -> grey."""
    t = np.clip((np.asarray(values, dtype=np.float64) - lo) / (hi - lo), 0, 1)
    pos = np.nan_to_num(t) * (len(_ANCHORS) - 1)
    rgb = np.stack(
        [np.interp(pos, np.arange(len(_ANCHORS)), _ANCHORS[:, c]) for c in range(3)], axis=-1
    )
    rgb[~np.isfinite(values)] = NO_VALUE_RGB
    out: NDArray[np.uint8] = rgb.astype(np.uint8)
    return out


def _ticks(lo: float, hi: float, count: int = 6) -> list[float]:
    raw = (hi - lo) / max(count - 1, 1)
    magnitude = 10 ** np.floor(np.log10(raw))
    step = min((m * magnitude for m in (1, 2, 2.5, 5, 10) if m * magnitude >= raw), default=raw)
    first = np.ceil(lo / step) * step
    return [float(v) + 0.0 for v in np.arange(first, hi + step * 1e-6, step)]  # no "-0"


def map_picture(
    values: NDArray[np.floating],
    *,
    lo: float,
    hi: float,
    unit: str,
    title: str,
    no_value: str = "no value",
    cell: int = 8,
) -> NDArray[np.uint8]:
    """A coloured map with a colour bar labelled in ``unit`` and a legend for NaN cells.

    Parameters
    ----------
    values
        The map (tiles-Y, tiles-X); NaN where there is no value (shown grey).
    lo, hi
        The values at the two ends of the colour bar (values beyond are clipped to it).
    unit, title
        The bar's unit ("px", "mm") and the picture's title.
    no_value
        The legend of the grey cells (e.g. "no texture (strength < 0.15)").
    cell
        Pixels per map cell.
    """
    if not hi > lo:
        raise ValueError(f"colour bar {lo}..{hi}: need hi > lo")
    body = colour_map(values, lo, hi).repeat(cell, axis=0).repeat(cell, axis=1)
    h, w = body.shape[:2]
    margin, bar_w, label_w, top, legend_h = 10, 18, 70, 24, 26
    height = max(h, 160) + top + legend_h + margin
    width = margin + w + margin + bar_w + label_w
    canvas = Image.new("RGB", (width, height), (255, 255, 255))
    canvas.paste(Image.fromarray(body), (margin, top))
    draw = ImageDraw.Draw(canvas)
    draw.text((margin, 6), title, fill=(0, 0, 0))
    bar_x, bar_h = margin + w + margin, max(h, 160)
    ramp = np.linspace(hi, lo, bar_h)[:, None].repeat(bar_w, axis=1)
    canvas.paste(Image.fromarray(colour_map(ramp, lo, hi)), (bar_x, top))
    draw.rectangle((bar_x, top, bar_x + bar_w - 1, top + bar_h - 1), outline=(0, 0, 0))
    for v in _ticks(lo, hi):
        y = top + round((hi - v) / (hi - lo) * (bar_h - 1))
        draw.line((bar_x + bar_w, y, bar_x + bar_w + 4, y), fill=(0, 0, 0))
        draw.text((bar_x + bar_w + 6, y - 5), f"{v:g} {unit}", fill=(0, 0, 0))
    ly = top + bar_h + 8
    draw.rectangle((margin, ly, margin + 12, ly + 12), fill=NO_VALUE_RGB, outline=(0, 0, 0))
    draw.text((margin + 18, ly + 1), no_value, fill=(0, 0, 0))
    return np.asarray(canvas, dtype=np.uint8)


def save_map_picture(values: NDArray[np.floating], path: str | Path, **options: Any) -> Path:
    """Write `map_picture` as a PNG and return its path."""
    path = Path(path)
    Image.fromarray(map_picture(values, **options)).save(path)
    return path
