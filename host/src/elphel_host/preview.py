"""8-bit pictures for people to look at: frame previews and maps with a colour bar.

A Bayer frame is demosaiced at full resolution (OpenCV's bilinear demosaic) and
white-balanced by `white_balance` (grey world: each colour scaled so its mean over the
mid-tones equals green's), then stretched to 8 bits with a display gamma; an RGB image
made from Bayer frames (a fused burst) is balanced by the same function. ``mosaic=True``
shows the raw mosaic as grey instead, pixel for pixel.

`map_picture` colours a map (disparity in px, depth in mm or m) through one perceptual
colour map (the anchors of matplotlib's *viridis*), scaled by default to the data's robust
range (`robust_range`: 2nd to 98th percentile), with a colour bar in its unit. Cells left
out (texture-less, far, ...) are painted in colours that are not on the map (`Swatch`)
and named in the legend, which also counts the cells beyond the bar's ends.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from PIL import Image, ImageDraw, ImageFont

from elphel_host.fileio import replacing

RGB = tuple[int, int, int]
Font = ImageFont.ImageFont | ImageFont.FreeTypeFont

# OpenCV names a Bayer pattern by the second row's second and third pixels, not the first
# row's: a GRBG sensor is cv2's "GB" (checked on all four by tests/host/test_preview.py).
_CV_BAYER = {"RGGB": "BG", "GRBG": "GB", "GBRG": "GR", "BGGR": "RG"}
# viridis at 0, 1/8, ..., 1: dark purple -> blue -> green -> yellow
_ANCHORS = np.array(
    [
        (68, 1, 84),
        (71, 44, 122),
        (59, 81, 139),
        (44, 113, 142),
        (33, 144, 141),
        (39, 173, 129),
        (92, 200, 99),
        (170, 220, 50),
        (253, 231, 37),
    ],
    dtype=np.float64,
)
#: Colours of cells without a value: light and unsaturated, unlike any colour of the map
#: (whose dark end is a dark purple and whose light end a saturated yellow).
NO_VALUE_RGB: RGB = (200, 200, 200)
FAR_RGB: RGB = (170, 215, 255)
DISAGREE_RGB: RGB = (250, 170, 210)
BACKGROUND_RGB: RGB = (255, 255, 255)
TEXT_RGB: RGB = (0, 0, 0)
FONT_PX = 12
#: Space above and below a colour bar for its end labels.
BAR_PAD_PX = FONT_PX // 2 + 2

#: Percentiles of the finite values at the ends of a colour bar by default.
ROBUST_PERCENTILES = (2.0, 98.0)


@lru_cache(maxsize=4)
def label_font(size_px: int = FONT_PX) -> Font:
    """The font of every label: DejaVu Sans where installed, else Pillow's own (scalable)."""
    try:
        return ImageFont.truetype("DejaVuSans.ttf", size_px)
    except OSError:
        return ImageFont.load_default(size=size_px)


def text_width(text: str, font: Font | None = None) -> int:
    """Width in pixels of ``text`` drawn in ``font`` (`label_font` by default)."""
    return int(np.ceil((font or label_font()).getlength(text)))


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


def white_balance_gains(rgb: NDArray[np.floating]) -> NDArray[np.float64]:
    """Grey-world gains (3,) on the mid-tones: R and B scaled so their means equal G's.

    Pixels in the top 1% of brightness (highlights, clipped areas) and the darkest 1% are
    left out of the means, so a few saturated pixels do not tint the picture.
    """
    flat = np.asarray(rgb, dtype=np.float64).reshape(-1, 3)
    luma = flat.mean(axis=-1)
    lo, hi = np.percentile(luma, [1, 99])
    mid = (luma >= lo) & (luma <= hi)
    if not mid.any():
        return np.ones(3)
    means = flat[mid].mean(axis=0)
    gains: NDArray[np.float64] = means[1] / np.maximum(means, 1e-12)
    return gains


def white_balance(
    rgb: NDArray[np.floating], *, gains: NDArray[np.floating] | None = None
) -> NDArray[np.float64]:
    """``rgb`` (..., 3) grey-world balanced: the one white balance of every picture.

    ``gains`` (3,) are applied instead when given (e.g. one image's gains for several
    images shown side by side); by default they are `white_balance_gains` of ``rgb``.
    """
    a = np.asarray(rgb, dtype=np.float64)
    if a.shape[-1:] != (3,):
        raise ValueError(f"white balance needs RGB (..., 3); got shape {a.shape}")
    return a * (white_balance_gains(a) if gains is None else np.asarray(gains, np.float64))


def preview_rgb(
    image: NDArray[Any], bayer: str | None, *, mosaic: bool = False
) -> NDArray[np.uint8]:
    """An 8-bit picture of a frame: RGB demosaiced and white-balanced, or grey.

    Parameters
    ----------
    image
        A raw frame (H, W) of any integer or float type, or an RGB image (H, W, 3) made
        from Bayer frames (a fused burst), which is white-balanced the same way.
    bayer
        The raw frame's mosaic ("GRBG", ...), or None for a mono sensor (grey) or an
        RGB image.
    mosaic
        Show the raw mosaic as grey, pixel for pixel, instead of colour.
    """
    a = np.asarray(image, dtype=np.float64)
    if a.ndim == 3:
        return _stretch(white_balance(a))
    if bayer is None or mosaic:
        return _stretch(a)
    return _stretch(white_balance(demosaic(image, bayer)))


def save_png(picture: NDArray[np.uint8], path: str | Path) -> Path:
    """Write an 8-bit picture as a PNG, atomically, and return its path."""
    path = Path(path)
    with replacing(path, sync=True, keep_suffix=True) as tmp:
        Image.fromarray(picture).save(tmp, format="PNG")
    return path


def save_preview(
    image: NDArray[Any], path: str | Path, *, bayer: str | None = None, mosaic: bool = False
) -> Path:
    """Write a PNG preview of a frame or an RGB image (see `preview_rgb`); return its path."""
    return save_png(preview_rgb(image, bayer, mosaic=mosaic), path)


def labelled_row(panels: Sequence[tuple[str, NDArray[Any]]]) -> NDArray[np.uint8]:
    """Images of one shape side by side, each under its label, on one tone scale.

    The row is toned (and, RGB, white-balanced) as one image by `preview_rgb`, so the
    panels compare; each label is drawn above its panel.
    """
    if not panels:
        raise ValueError("panels is empty; allowed: one or more (label, image) pairs")
    shape = np.shape(panels[0][1])
    for label, image in panels:
        if np.shape(image) != shape:
            raise ValueError(f"panel {label!r} has shape {np.shape(image)}; allowed: {shape}")
    gap, label_h = 4, FONT_PX + 8
    w = shape[1]
    row = np.concatenate([np.asarray(im, np.float64) for _, im in panels], axis=1)
    toned = Image.fromarray(preview_rgb(row, None)).convert("RGB")
    sheet = Image.new("RGB", (len(panels) * (w + gap) - gap, shape[0] + label_h), BACKGROUND_RGB)
    draw = ImageDraw.Draw(sheet)
    for i, (label, _) in enumerate(panels):
        sheet.paste(toned.crop((i * w, 0, (i + 1) * w, shape[0])), (i * (w + gap), label_h))
        draw.text((i * (w + gap) + 2, 3), label, fill=TEXT_RGB, font=label_font())
    return np.asarray(sheet, dtype=np.uint8)


def colour_map(values: NDArray[np.floating], lo: float, hi: float) -> NDArray[np.uint8]:
    """RGB (..., 3) of ``values`` along viridis from ``lo`` to ``hi``; NaN -> `NO_VALUE_RGB`.

    Values beyond the ends take the end colours.
    """
    v = np.asarray(values, dtype=np.float64)
    span = hi - lo if hi > lo else 1.0
    t = np.clip((np.nan_to_num(v, nan=lo) - lo) / span, 0.0, 1.0) * (len(_ANCHORS) - 1)
    i = np.minimum(np.floor(t).astype(np.intp), len(_ANCHORS) - 2)
    f = (t - i)[..., None]
    rgb = _ANCHORS[i] * (1 - f) + _ANCHORS[i + 1] * f
    rgb[~np.isfinite(v)] = NO_VALUE_RGB
    out: NDArray[np.uint8] = np.round(rgb).astype(np.uint8)
    return out


def robust_range(
    values: NDArray[np.floating], percentiles: tuple[float, float] = ROBUST_PERCENTILES
) -> tuple[float, float]:
    """The ``percentiles`` of the finite values: a colour bar's ends, hi > lo.

    A constant map gets a bar one unit wide around its value; a map without a finite
    value gets 0..1.
    """
    v = np.asarray(values, dtype=np.float64)
    finite = v[np.isfinite(v)]
    if finite.size == 0:
        return 0.0, 1.0
    lo, hi = (float(x) for x in np.percentile(finite, percentiles))
    if not hi > lo:
        return lo - 0.5, lo + 0.5
    return lo, hi


def ticks(lo: float, hi: float, count: int = 6) -> list[float]:
    """Round values (1, 2, 2.5 or 5 times a power of ten apart) from ``lo`` to ``hi``."""
    raw = (hi - lo) / max(count - 1, 1)
    if not raw > 0:
        return [lo]
    magnitude = 10 ** np.floor(np.log10(raw))
    step = min((m * magnitude for m in (1, 2, 2.5, 5, 10) if m * magnitude >= raw), default=raw)
    first = np.ceil(lo / step) * step
    return [float(v) + 0.0 for v in np.arange(first, hi + step * 1e-6, step)]  # no "-0"


def tick_text(value: float) -> str:
    """A tick's label: plain digits from 0.001 to 99999, else 3 significant digits."""
    if value != 0 and not 1e-3 <= abs(value) < 1e5:
        return f"{value:.3g}"
    return f"{round(value, 6):g}"


def number_text(value: float) -> str:
    """A measured value for a label: 3 significant digits, plain from 0.001 to 99999."""
    if value == 0 or not np.isfinite(value):
        return f"{value:g}"
    if not 1e-3 <= abs(value) < 1e5:
        return f"{value:.3g}"
    decimals = max(0, 2 - int(np.floor(np.log10(abs(value)))))
    text = f"{value:.{decimals}f}"
    return text.rstrip("0").rstrip(".") if decimals else text


@dataclass(frozen=True, eq=False)
class Swatch:
    """Cells of a map painted in a colour outside the colour map, named in the legend.

    Attributes
    ----------
    label
        What the cells are ("no texture (strength < 0.15)").
    mask
        True on those cells (the map's shape).
    rgb
        Their colour (one of `NO_VALUE_RGB`, `FAR_RGB`, `DISAGREE_RGB` or another colour
        that is not on the map).
    """

    label: str
    mask: NDArray[np.bool_]
    rgb: RGB


def map_legend(
    values: NDArray[np.floating],
    *,
    lo: float,
    hi: float,
    unit: str,
    swatches: Sequence[Swatch] = (),
    no_value: str = "no value",
) -> list[tuple[RGB | None, str]]:
    """The legend lines of `map_picture`: (colour or None, text), one per line.

    One line per swatch that covers a cell, one for NaN cells no swatch covers, and one
    counting the cells beyond the colour bar's ends (shown in its end colours).
    """
    v = np.asarray(values, dtype=np.float64)
    covered = np.zeros(v.shape, dtype=bool)
    lines: list[tuple[RGB | None, str]] = []
    for s in swatches:
        covered |= s.mask
        if s.mask.any():
            lines.append((s.rgb, s.label))
    if (~np.isfinite(v) & ~covered).any():
        lines.append((NO_VALUE_RGB, no_value))
    with np.errstate(invalid="ignore"):
        below = int(np.count_nonzero((v < lo) & ~covered))
        above = int(np.count_nonzero((v > hi) & ~covered))
    if below or above:
        lines.append(
            (
                None,
                f"{below} below {number_text(lo)} {unit} and {above} above "
                f"{number_text(hi)} {unit} shown in the bar's end colours",
            )
        )
    return lines


def map_picture(
    values: NDArray[np.floating],
    *,
    unit: str,
    title: str,
    lo: float | None = None,
    hi: float | None = None,
    swatches: Sequence[Swatch] = (),
    no_value: str = "no value",
    cell: int = 8,
) -> NDArray[np.uint8]:
    """A coloured map with a colour bar labelled in ``unit`` and a legend (see `map_legend`).

    Parameters
    ----------
    values
        The map (rows, columns); NaN where there is no value.
    unit, title
        The bar's unit ("px", "mm") and the picture's title.
    lo, hi
        The values at the two ends of the colour bar; by default the `robust_range` of
        the values no swatch covers.
    swatches
        Cells painted in colours that are not on the colour map, each named in the legend.
    no_value
        The legend of NaN cells no swatch covers (painted `NO_VALUE_RGB`).
    cell
        Pixels per map cell.
    """
    v = np.asarray(values, dtype=np.float64).copy()
    for s in swatches:
        if s.mask.shape != v.shape:
            raise ValueError(f"swatch {s.label!r} has shape {s.mask.shape}; allowed: {v.shape}")
        v[s.mask] = np.nan
    auto = robust_range(v)
    lo, hi = auto[0] if lo is None else lo, auto[1] if hi is None else hi
    if not hi > lo:
        raise ValueError(f"colour bar {lo}..{hi}: need hi > lo")
    body = colour_map(v, lo, hi)
    for s in swatches:
        body[s.mask] = s.rgb
    legend = map_legend(
        np.asarray(values, np.float64),
        lo=lo,
        hi=hi,
        unit=unit,
        swatches=swatches,
        no_value=no_value,
    )
    body = body.repeat(cell, axis=0).repeat(cell, axis=1)
    return _map_canvas(body, lo=lo, hi=hi, unit=unit, title=title, legend=legend)


def colour_bar(lo: float, hi: float, *, unit: str, height_px: int) -> Image.Image:
    """The colour bar from ``hi`` (top) to ``lo``, ticks labelled in ``unit`` at its right.

    The bar starts `BAR_PAD_PX` below the image's top and ends as far above its bottom,
    so the end labels are not cut.
    """
    bar_w, pad = 18, BAR_PAD_PX
    labels = [(v, f"{tick_text(v)} {unit}") for v in ticks(lo, hi)]
    width = bar_w + 7 + max(text_width(t) for _, t in labels) + 4
    img = Image.new("RGB", (width, height_px + 2 * pad), BACKGROUND_RGB)
    ramp = np.linspace(hi, lo, height_px)[:, None].repeat(bar_w, axis=1)
    img.paste(Image.fromarray(colour_map(ramp, lo, hi)), (0, pad))
    draw = ImageDraw.Draw(img)
    draw.rectangle((0, pad, bar_w - 1, pad + height_px - 1), outline=TEXT_RGB)
    for v, text in labels:
        y = pad + round((hi - v) / (hi - lo) * (height_px - 1))
        draw.line((bar_w, y, bar_w + 4, y), fill=TEXT_RGB)
        draw.text((bar_w + 7, y - FONT_PX // 2 - 1), text, fill=TEXT_RGB, font=label_font())
    return img


def _map_canvas(
    body: NDArray[np.uint8],
    *,
    lo: float,
    hi: float,
    unit: str,
    title: str,
    legend: list[tuple[RGB | None, str]],
) -> NDArray[np.uint8]:
    """The coloured cells, the bar with its ticks at the right, the legend below."""
    font, line_h = label_font(), FONT_PX + 6
    h, w = body.shape[:2]
    margin, top = 10, FONT_PX + 12
    bar = colour_bar(lo, hi, unit=unit, height_px=max(h, 160))
    legend_w = max((text_width(t) + 18 for _, t in legend), default=0)
    width = margin + max(w + margin + bar.width, legend_w, text_width(title)) + margin
    height = top + max(h, 160) + BAR_PAD_PX + 8 + line_h * len(legend) + margin
    canvas = Image.new("RGB", (width, height), BACKGROUND_RGB)
    canvas.paste(Image.fromarray(body), (margin, top))
    canvas.paste(bar, (margin + w + margin, top - BAR_PAD_PX))
    draw = ImageDraw.Draw(canvas)
    draw.text((margin, 5), title, fill=TEXT_RGB, font=font)
    y = top + max(h, 160) + BAR_PAD_PX + 8
    for rgb, text in legend:
        x = margin
        if rgb is not None:
            draw.rectangle((x, y, x + 12, y + 12), fill=rgb, outline=TEXT_RGB)
            x += 18
        draw.text((x, y), text, fill=TEXT_RGB, font=font)
        y += line_h
    return np.asarray(canvas, dtype=np.uint8)


def save_map_picture(values: NDArray[np.floating], path: str | Path, **options: Any) -> Path:
    """Write `map_picture` as a PNG and return its path."""
    return save_png(map_picture(values, **options), path)
