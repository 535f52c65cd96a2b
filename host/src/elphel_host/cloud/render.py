"""Pictures of depth maps, point clouds and distance histograms (PNG, drawn with Pillow).

Colours, the colour bar, the legend and the font are those of `elphel_host.preview`: one
colour map (viridis), scaled to the data's robust range, with left-out cells in colours
that are not on it. A point cloud is drawn as two orthographic views with axes in mm
(or m, for scenes beyond 10 m): from the camera (x right, y down) and from above (x
right, z away from the camera upwards), its points coloured by their depth z.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from PIL import Image, ImageDraw

from elphel_host.cloud.ply import PointCloud
from elphel_host.preview import (
    BACKGROUND_RGB,
    FONT_PX,
    TEXT_RGB,
    Swatch,
    colour_bar,
    colour_map,
    label_font,
    map_picture,
    number_text,
    robust_range,
    save_png,
    text_width,
    tick_text,
    ticks,
)

U8 = NDArray[np.uint8]
F64 = NDArray[np.float64]

#: Lengths from this many mm on are shown in metres.
METRES_FROM_MM = 10_000.0
_BAR_RGB = (59, 81, 139)


def length_unit(span_mm: float) -> tuple[str, float]:
    """The unit lengths up to ``span_mm`` are shown in: ("mm", 1.0) or ("m", 1000.0)."""
    return ("m", 1000.0) if span_mm >= METRES_FROM_MM else ("mm", 1.0)


def depth_png(
    path: str | Path,
    depth_mm: NDArray[np.floating],
    *,
    title: str = "depth",
    swatches: Sequence[Swatch] = (),
) -> Path:
    """The depth map over its robust range, with a colour bar in mm (m beyond 10 m).

    ``swatches`` name the tiles left out (texture-less, far, ...); NaN tiles no swatch
    covers are named "no depth".
    """
    d = np.asarray(depth_mm, dtype=np.float64).copy()
    for s in swatches:
        d[s.mask] = np.nan
    unit, per = length_unit(robust_range(d)[1])
    cell = max(1, int(np.ceil(400 / max(1, min(d.shape)))))
    picture = map_picture(
        d / per, unit=unit, title=title, swatches=swatches, no_value="no depth", cell=cell
    )
    return save_png(picture, path)


@dataclass(frozen=True)
class Axis:
    """One axis of a view: the range shown and its label."""

    lo: float
    hi: float
    label: str


def _axis(values: F64, label: str) -> Axis:
    lo, hi = robust_range(values, (1.0, 99.0))
    pad = 0.05 * (hi - lo)
    return Axis(lo - pad, hi + pad, label)


def _plot_area(draw: ImageDraw.ImageDraw, box: tuple[int, int, int, int], u: Axis, v: Axis) -> None:
    """The frame of a view, its ticks and tick labels, and the axis labels."""
    x0, y0, x1, y1 = box
    font = label_font()
    draw.rectangle(box, outline=TEXT_RGB)
    for t in ticks(u.lo, u.hi, 5):
        x = x0 + round((t - u.lo) / (u.hi - u.lo) * (x1 - x0))
        draw.line((x, y1, x, y1 + 4), fill=TEXT_RGB)
        text = tick_text(t)
        draw.text((x - text_width(text) // 2, y1 + 6), text, fill=TEXT_RGB, font=font)
    draw.text(
        ((x0 + x1 - text_width(u.label)) // 2, y1 + 8 + FONT_PX), u.label, fill=TEXT_RGB, font=font
    )
    for t in ticks(min(v.lo, v.hi), max(v.lo, v.hi), 5):
        y = y0 + round((t - v.lo) / (v.hi - v.lo) * (y1 - y0))
        draw.line((x0 - 4, y, x0, y), fill=TEXT_RGB)
        text = tick_text(t)
        draw.text((x0 - 7 - text_width(text), y - FONT_PX // 2 - 1), text, fill=TEXT_RGB, font=font)
    draw.text((x0, y0 - FONT_PX - 4), v.label, fill=TEXT_RGB, font=font)


def scatter_view(
    u: F64, v: F64, rgb: U8, *, u_axis: Axis, v_axis: Axis, title: str, size_px: int = 360
) -> Image.Image:
    """Points at (u, v) in their colours, in the given order (later points on top), with axes.

    ``v`` grows downwards when ``v_axis.lo`` < ``v_axis.hi`` (image rows), upwards when
    it is the other way round. Points outside the axes' ranges are not drawn.
    """
    left, top, right, bottom = 64, 2 * FONT_PX + 14, 14, 2 * FONT_PX + 16
    panel = Image.new("RGB", (left + size_px + right, top + size_px + bottom), BACKGROUND_RGB)
    img = np.asarray(panel).copy()
    col = np.round((u - u_axis.lo) / (u_axis.hi - u_axis.lo) * (size_px - 2)).astype(np.intp)
    row = np.round((v - v_axis.lo) / (v_axis.hi - v_axis.lo) * (size_px - 2)).astype(np.intp)
    ok = (col >= 0) & (col < size_px - 1) & (row >= 0) & (row < size_px - 1)
    for dc in (0, 1):  # 2x2 splats
        for dr in (0, 1):
            img[top + row[ok] + dr, left + col[ok] + dc] = rgb[ok]
    panel = Image.fromarray(img)
    draw = ImageDraw.Draw(panel)
    draw.text((left, 3), title, fill=TEXT_RGB, font=label_font())
    _plot_area(draw, (left, top, left + size_px - 1, top + size_px - 1), u_axis, v_axis)
    return panel


def cloud_caption(total: int, drawn: int, *, far: int, far_mm: float | None, title: str) -> str:
    """The first line of a cloud's picture: how many points are drawn and why not all."""
    text = f"{title}: {drawn} of {total} points drawn, coloured by depth z".lstrip(": ")
    if far and far_mm is not None:
        unit, per = length_unit(far_mm)
        text += f"; {far} far points (beyond {number_text(far_mm / per)} {unit}) left out"
    return text


def cloud_picture(cloud: PointCloud, *, far_mm: float | None = None, title: str = "") -> U8:
    """The cloud from the camera and from above, coloured by depth, with a colour bar.

    Points farther than ``far_mm`` (their depth is mostly noise) are left out and counted
    in the caption; the axes span the 1st to 99th percentile of the others (padded 5 %).
    """
    xyz = np.asarray(cloud.xyz, dtype=np.float64)
    keep = np.isfinite(xyz).all(axis=1)
    far = 0
    if far_mm is not None:
        far = int(np.count_nonzero(keep & (xyz[:, 2] > far_mm)))
        keep &= xyz[:, 2] <= far_mm
    unit, per = length_unit(float(np.ptp(xyz[keep, 2])) if keep.any() else 0.0)
    p = xyz[keep] / per
    z_range = robust_range(p[:, 2])
    rgb = colour_map(p[:, 2], *z_range)
    x_axis = _axis(p[:, 0], f"x ({unit}), right")
    z_axis = _axis(p[:, 2], f"z ({unit}), away from the camera")
    views = [
        # from the camera: nearer points on top; from above: higher points (smaller y) on top
        (np.argsort(-p[:, 2]), 1, _axis(p[:, 1], f"y ({unit}), down"), "seen from the camera"),
        (np.argsort(-p[:, 1]), 2, Axis(z_axis.hi, z_axis.lo, z_axis.label), "seen from above"),
    ]
    panels = [
        scatter_view(p[o, 0], p[o, k], rgb[o], u_axis=x_axis, v_axis=v, title=name)
        for o, k, v, name in views
    ]
    caption = cloud_caption(len(xyz), len(p), far=far, far_mm=far_mm, title=title)
    return _cloud_sheet(panels, z_range, unit=unit, caption=caption)


def _cloud_sheet(
    panels: list[Image.Image], z_range: tuple[float, float], *, unit: str, caption: str
) -> U8:
    """The views side by side under the caption, the depth colour bar at the right."""
    bar_img = colour_bar(*z_range, unit=unit, height_px=240)
    top = FONT_PX + 10
    bar_title = f"depth z ({unit})"
    width = sum(p.width for p in panels) + 10 + max(bar_img.width, text_width(bar_title)) + 10
    width = max(width, text_width(caption) + 16)
    height = top + max(max(p.height for p in panels), bar_img.height)
    sheet = Image.new("RGB", (width, height), BACKGROUND_RGB)
    x = 0
    for p in panels:
        sheet.paste(p, (x, top))
        x += p.width
    sheet.paste(bar_img, (x + 10, top + 2 * FONT_PX))
    draw = ImageDraw.Draw(sheet)
    draw.text((x + 10, top + FONT_PX - 2), bar_title, fill=TEXT_RGB, font=label_font())
    draw.text((8, 4), caption, fill=TEXT_RGB, font=label_font())
    return np.asarray(sheet, dtype=np.uint8)


def cloud_png(
    path: str | Path, cloud: PointCloud, *, far_mm: float | None = None, title: str = ""
) -> Path:
    """Write `cloud_picture` as a PNG and return its path."""
    return save_png(cloud_picture(cloud, far_mm=far_mm, title=title), path)


def histogram_range_mm(distances_mm: F64) -> float:
    """A histogram's robust end: the 99.5th percentile, at most 3 times the 95th (> 0).

    A few gross outliers (1 % of points kilometres away) then do not squeeze the bulk of
    the distances into the first bin.
    """
    if distances_mm.size == 0:
        return 1.0
    p95, p995 = (float(v) for v in np.percentile(distances_mm, [95, 99.5]))
    hi = min(p995, 3 * p95)
    return hi if hi > 0 else max(float(distances_mm.max()), 1.0)


def histogram_caption(distances_mm: F64, max_mm: float, *, title: str) -> str:
    """A histogram's title line: the points in all, and how many lie beyond its range."""
    caption = f"{title}: {distances_mm.size} points"
    beyond = int(np.count_nonzero(distances_mm > max_mm))
    if beyond:
        caption += f", {beyond} beyond {number_text(max_mm)} mm not shown"
    return caption


def histogram_png(
    path: str | Path,
    distances_mm: NDArray[np.floating],
    *,
    bins: int = 50,
    max_mm: float | None = None,
    title: str = "cloud-to-cloud distance",
) -> Path:
    """A histogram of distances (mm) with the median and 95th percentile marked.

    It spans 0 .. ``max_mm`` (by default `histogram_range_mm`); the distances beyond are
    not lumped into the last bin but counted in the title.
    """
    d = np.asarray(distances_mm, dtype=np.float64)
    d = d[np.isfinite(d)]
    hi = max_mm if max_mm is not None else histogram_range_mm(d)
    counts, _edges = np.histogram(d[d <= hi], bins=bins, range=(0.0, hi))
    img = Image.new("RGB", (680, 380), BACKGROUND_RGB)
    draw = ImageDraw.Draw(img)
    draw.text((10, 6), histogram_caption(d, hi, title=title), fill=TEXT_RGB, font=label_font())
    if d.size:
        _histogram_axes(draw, counts, hi, box=(70, 40, 680 - 40, 380 - 48))
        _histogram_marks(draw, d, hi, box=(70, 40, 680 - 40, 380 - 48))
    return save_png(np.asarray(img, dtype=np.uint8), path)


def _histogram_axes(
    draw: ImageDraw.ImageDraw,
    counts: NDArray[np.intp],
    hi: float,
    *,
    box: tuple[int, int, int, int],
) -> None:
    """Bars, both axes with their ticks, and the unit."""
    x0, y0, x1, y1 = box
    font, bins = label_font(), len(counts)
    cmax = max(int(counts.max()), 1)
    for i, c in enumerate(counts):
        left = x0 + int(i * (x1 - x0) / bins)
        right = x0 + int((i + 1) * (x1 - x0) / bins) - 1
        draw.rectangle(
            (left, y1 - round(c / cmax * (y1 - y0)), max(left, right), y1), fill=_BAR_RGB
        )
    draw.line((x0, y1, x1, y1), fill=TEXT_RGB)
    draw.line((x0, y0, x0, y1), fill=TEXT_RGB)
    draw.text((10, y0 - FONT_PX - 6), "points", fill=TEXT_RGB, font=font)
    for t in ticks(0.0, hi, 6):
        x = x0 + round(t / hi * (x1 - x0))
        draw.line((x, y1, x, y1 + 4), fill=TEXT_RGB)
        text = tick_text(t)
        draw.text((x - text_width(text) // 2, y1 + 6), text, fill=TEXT_RGB, font=font)
    draw.text(
        (x1 - text_width("distance (mm)"), y1 + 8 + FONT_PX),
        "distance (mm)",
        fill=TEXT_RGB,
        font=font,
    )
    for t in ticks(0.0, float(cmax), 5):
        y = y1 - round(t / cmax * (y1 - y0))
        draw.line((x0 - 4, y, x0, y), fill=TEXT_RGB)
        text = tick_text(t)
        draw.text((x0 - 7 - text_width(text), y - FONT_PX // 2 - 1), text, fill=TEXT_RGB, font=font)


def _histogram_marks(
    draw: ImageDraw.ImageDraw, d: F64, hi: float, *, box: tuple[int, int, int, int]
) -> None:
    """The median and the 95th percentile as labelled vertical lines."""
    x0, y0, x1, y1 = box
    for k, (name, value, colour) in enumerate(
        (("median", np.median(d), (200, 0, 0)), ("p95", np.percentile(d, 95), (230, 140, 0)))
    ):
        x = x0 + round(min(float(value), hi) / hi * (x1 - x0))
        draw.line((x, y0, x, y1), fill=colour, width=2)
        text = f"{name} {number_text(float(value))} mm"
        tx = x + 4 if x + 4 + text_width(text) <= x1 else x - 4 - text_width(text)
        draw.text((tx, y0 + 2 + k * (FONT_PX + 4)), text, fill=colour, font=label_font())
