"""Pictures of depth maps, point clouds and distance histograms (PNG, drawn with Pillow).

A depth map or a distance is coloured through one perceptual colour map (anchors of
matplotlib's *viridis*, interpolated linearly) and always shown with a colour bar that
names its unit; a point cloud is drawn as an oblique orthographic view with a depth
buffer, so nearer points hide farther ones.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from PIL import Image, ImageDraw, ImageFont

from elphel_host.cloud.ply import PointCloud
from elphel_host.fileio import replacing

U8 = NDArray[np.uint8]

# viridis at 0, 1/8, ..., 1
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
_NAN_RGB = (40, 40, 40)
_BG = (255, 255, 255)


def colour_map(values: NDArray[np.floating], vmin: float, vmax: float) -> U8:
    """RGB ``(..., 3)`` uint8 of ``values`` on [vmin, vmax]; NaN is dark grey."""
    v = np.asarray(values, dtype=np.float64)
    span = vmax - vmin if vmax > vmin else 1.0
    t = np.clip((np.nan_to_num(v, nan=vmin) - vmin) / span, 0.0, 1.0) * (len(_ANCHORS) - 1)
    i = np.minimum(np.floor(t).astype(np.intp), len(_ANCHORS) - 2)
    f = (t - i)[..., None]
    rgb = _ANCHORS[i] * (1 - f) + _ANCHORS[i + 1] * f
    rgb[~np.isfinite(v)] = _NAN_RGB
    out: U8 = np.round(rgb).astype(np.uint8)
    return out


def _font() -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    return ImageFont.load_default()


def _ticks(vmin: float, vmax: float, n: int = 5) -> list[float]:
    if not vmax > vmin:
        return [vmin]
    return [float(x) for x in np.linspace(vmin, vmax, n)]


def _save(img: Image.Image, path: str | Path) -> Path:
    path = Path(path)
    with replacing(path, sync=True, keep_suffix=True) as tmp:
        img.save(tmp, format="PNG")
    return path


def with_colour_bar(
    rgb: U8, vmin: float, vmax: float, *, unit: str, title: str = ""
) -> Image.Image:
    """An image with a vertical colour bar at its right, labelled in ``unit``."""
    h, w = rgb.shape[:2]
    bar_w, label_w, top = 24, 90, 24
    canvas = Image.new("RGB", (w + bar_w + label_w + 20, h + top + 10), _BG)
    canvas.paste(Image.fromarray(rgb), (0, top))
    ramp = np.linspace(vmax, vmin, h)[:, None].repeat(bar_w, axis=1)
    canvas.paste(Image.fromarray(colour_map(ramp, vmin, vmax)), (w + 10, top))
    draw = ImageDraw.Draw(canvas)
    font = _font()
    for value in _ticks(vmin, vmax):
        frac = 0.0 if vmax <= vmin else (vmax - value) / (vmax - vmin)
        y = top + round(frac * (h - 1))
        draw.line([(w + 10 + bar_w, y), (w + 14 + bar_w, y)], fill=(0, 0, 0))
        draw.text(
            (w + 18 + bar_w, max(top, y - 6)), f"{value:.4g} {unit}", fill=(0, 0, 0), font=font
        )
    if title:
        draw.text((4, 4), title, fill=(0, 0, 0), font=font)
    return canvas


def _upscale(rgb: U8, min_size: int = 400) -> U8:
    k = max(1, int(np.ceil(min_size / max(1, min(rgb.shape[:2])))))
    out: U8 = np.repeat(np.repeat(rgb, k, axis=0), k, axis=1) if k > 1 else rgb
    return out


def depth_png(path: str | Path, depth_mm: NDArray[np.floating], *, title: str = "depth") -> Path:
    """The depth map coloured from its 1st to 99th percentile, with a colour bar in mm."""
    d = np.asarray(depth_mm, dtype=np.float64)
    finite = d[np.isfinite(d)]
    lo, hi = (
        (float(np.percentile(finite, 1)), float(np.percentile(finite, 99)))
        if finite.size
        else (0.0, 1.0)
    )
    rgb = _upscale(colour_map(d, lo, hi))
    return _save(with_colour_bar(rgb, lo, hi, unit="mm", title=title + " (grey: no depth)"), path)


def cloud_view(
    cloud: PointCloud,
    *,
    size: tuple[int, int] = (800, 600),
    yaw_deg: float = 30.0,
    pitch_deg: float = 20.0,
    colours: U8 | None = None,
) -> U8:
    """An oblique orthographic view of the cloud ``(height, width, 3)`` uint8, depth-buffered."""
    w, h = size
    img = np.full((h, w, 3), _BG, dtype=np.uint8)
    if len(cloud) == 0:
        return img
    p = cloud.xyz.astype(np.float64)
    p = p - np.median(p, axis=0)
    a, b = np.radians(yaw_deg), np.radians(pitch_deg)
    ry = np.array([[np.cos(a), 0, -np.sin(a)], [0, 1, 0], [np.sin(a), 0, np.cos(a)]])
    rx = np.array([[1, 0, 0], [0, np.cos(b), np.sin(b)], [0, -np.sin(b), np.cos(b)]])
    q = p @ (rx @ ry).T
    lo, hi = np.percentile(q[:, :2], 2, axis=0), np.percentile(q[:, :2], 98, axis=0)
    scale = 0.9 * min(w / max(hi[0] - lo[0], 1e-9), h / max(hi[1] - lo[1], 1e-9))
    mid = 0.5 * (lo + hi)
    u = np.round((q[:, 0] - mid[0]) * scale + w / 2).astype(np.intp)
    v = np.round((q[:, 1] - mid[1]) * scale + h / 2).astype(np.intp)
    rgb = colours if colours is not None else cloud.rgb
    if rgb is None:
        rgb = colour_map(cloud.xyz[:, 2], *np.percentile(cloud.xyz[:, 2], [1, 99]))
    order = np.argsort(-q[:, 2])  # far first; nearer points overwrite them
    for du in (0, 1):  # 2x2 splats
        for dv in (0, 1):
            uu, vv = u[order] + du, v[order] + dv
            ok = (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
            img[vv[ok], uu[ok]] = rgb[order][ok]
    return img


def cloud_png(path: str | Path, cloud: PointCloud, *, title: str = "") -> Path:
    """An oblique view of the cloud in its own colours."""
    img = Image.fromarray(cloud_view(cloud))
    if title:
        ImageDraw.Draw(img).text((4, 4), title, fill=(0, 0, 0), font=_font())
    return _save(img, path)


def histogram_png(
    path: str | Path,
    distances_mm: NDArray[np.floating],
    *,
    bins: int = 50,
    title: str = "cloud-to-cloud distance",
) -> Path:
    """A histogram of distances (mm) with the median and 95th percentile marked."""
    d = np.asarray(distances_mm, dtype=np.float64)
    d = d[np.isfinite(d)]
    w, h, left, bottom, top = 640, 360, 60, 40, 30
    img = Image.new("RGB", (w, h), _BG)
    draw = ImageDraw.Draw(img)
    font = _font()
    draw.text((left, 8), f"{title} ({d.size} points)", fill=(0, 0, 0), font=font)
    if d.size == 0:
        return _save(img, path)
    hi = float(np.percentile(d, 99.5)) or float(d.max()) or 1.0
    counts, _edges = np.histogram(np.minimum(d, hi), bins=bins, range=(0.0, hi))
    pw, ph = w - left - 20, h - top - bottom
    cmax = max(int(counts.max()), 1)
    for i, c in enumerate(counts):
        x0 = left + int(i * pw / bins)
        x1 = left + int((i + 1) * pw / bins) - 1
        y0 = top + ph - round(c / cmax * ph)
        draw.rectangle([x0, y0, max(x0, x1), top + ph], fill=(59, 81, 139))
    draw.line([(left, top + ph), (left + pw, top + ph)], fill=(0, 0, 0))
    draw.line([(left, top), (left, top + ph)], fill=(0, 0, 0))
    for value in _ticks(0.0, hi):
        x = left + round(value / hi * pw)
        draw.line([(x, top + ph), (x, top + ph + 4)], fill=(0, 0, 0))
        draw.text((x - 12, top + ph + 6), f"{value:.3g}", fill=(0, 0, 0), font=font)
    draw.text((left + pw - 40, top + ph + 20), "mm", fill=(0, 0, 0), font=font)
    draw.text((4, top), str(cmax), fill=(0, 0, 0), font=font)
    for name, value, colour in (
        ("median", np.median(d), (200, 0, 0)),
        ("p95", np.percentile(d, 95), (230, 140, 0)),
    ):
        x = left + round(min(float(value), hi) / hi * pw)
        draw.line([(x, top), (x, top + ph)], fill=colour, width=2)
        draw.text(
            (x + 3, top + 2 if name == "median" else top + 14),
            f"{name} {float(value):.3g} mm",
            fill=colour,
            font=font,
        )
    return _save(img, path)
