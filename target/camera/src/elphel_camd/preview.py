"""Previews of raw frames for eyes: colour from Bayer mosaics, false colour for the Lepton.

Pure functions on arrays. `preview_rgb` turns a 16-bit frame into an 8-bit RGB image at a
power-of-two fraction of its size: a Bayer mosaic is demosaiced by binning (each 2x2
cell becomes one RGB pixel, then blocks are averaged down), white-balanced on the
frame's own grey world and gamma-encoded; a Lepton frame in TLinear units is mapped to a
palette between two temperatures. `encode_jpeg` compresses the result (Pillow), and
`histogram` counts a frame's raw values per colour with the clipped pixels.

The previews are for looking (focus, framing, exposure, synchrony), not for measuring:
the raw frame is what `POST /capture` delivers.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from PIL import Image

FACTORS = (1, 2, 4, 8)  # allowed reductions: scale 1, 1/2, 1/4, 1/8
KELVIN_C = 273.15
WB_GAIN_LIMITS = (0.25, 4.0)
_GAMMA = 1 / 2.2
HISTOGRAM_BINS = 64
_LUT_BITS = 12

# Palette anchors for thermal images, cold to hot (black, violet, red, orange, yellow, white).
PALETTE = ("#000000", "#2c0a6b", "#8a0f86", "#d2283d", "#f47a12", "#fcd23a", "#ffffff")


def _positions(bayer: str) -> dict[str, list[tuple[int, int]]]:
    if len(bayer) != 4 or sorted(bayer) != ["B", "G", "G", "R"]:
        raise ValueError(f"Bayer order {bayer!r}; allowed RGGB, GRBG, GBRG, BGGR")
    out: dict[str, list[tuple[int, int]]] = {"R": [], "G": [], "B": []}
    for i, colour in enumerate(bayer):
        out[colour].append((i // 2, i % 2))
    return out


def _block_mean(plane: NDArray[Any], factor: int) -> NDArray[np.float32]:
    """Average ``factor`` x ``factor`` blocks (the plane is cropped to whole blocks)."""
    if factor == 1:
        return plane.astype(np.float32)
    h, w = plane.shape[0] // factor, plane.shape[1] // factor
    blocks = plane[: h * factor, : w * factor].reshape(h, factor, w, factor)
    return (blocks.sum(axis=(1, 3), dtype=np.uint32) / (factor * factor)).astype(np.float32)


def bayer_rgb(image: NDArray[np.uint16], bayer: str, *, factor: int) -> NDArray[np.float32]:
    """Demosaic a Bayer frame by binning, to 1/``factor`` of its size.

    Parameters
    ----------
    image
        2-D mosaic, even height and width.
    bayer
        Order of the first 2x2 cell, e.g. ``"GRBG"``.
    factor
        Reduction, one of 1, 2, 4, 8. Below 2 the half-size colour image is doubled
        (pixel repetition): the binned demosaic resolves one colour pixel per cell.

    Returns
    -------
    ndarray
        (H / factor, W / factor, 3) float32 in the input's units.
    """
    _check(image, factor)
    where = _positions(bayer)
    cell = max(factor // 2, 1)
    sums = _cell_sums(image, cell)
    norm = np.float32(1 / (cell * cell))
    planes = []
    for colour in "RGB":
        sites = [sums[:, r, :, c] for r, c in where[colour]]
        total = sites[0] if len(sites) == 1 else sites[0] + sites[1]
        planes.append(total.astype(np.float32) * (norm / len(sites)))
    rgb = np.stack(planes, axis=-1)
    if factor == 1:
        rgb = rgb.repeat(2, axis=0).repeat(2, axis=1)
    return rgb


def _cell_sums(image: NDArray[np.uint16], cell: int, *, bits: int = 16) -> NDArray[Any]:
    """Sums over ``cell`` x ``cell`` blocks of 2x2 Bayer cells, per cell site.

    Returns (H', 2, W', 2): [block row, site row, block column, site column]. Rows are
    added first on contiguous memory, then columns: much faster than one ``sum`` over a
    strided 6-D view.
    """
    h, w = image.shape[0] // (2 * cell), image.shape[1] // (2 * cell)
    frame = image[: h * 2 * cell, : w * 2 * cell]
    rows = frame.reshape(h, cell, 2, w * 2 * cell)
    # 16-bit sums where they cannot overflow (12-bit pixels, up to 16 per sum): half the
    # memory traffic of 32-bit ones.
    wide = bits + 2 * (cell - 1).bit_length() > 16
    dtype = np.uint32 if wide else np.uint16
    acc: NDArray[Any] = (
        np.add(rows[:, 0], rows[:, 1], dtype=dtype) if cell > 1 else rows[:, 0].astype(dtype)
    )
    for k in range(2, cell):
        acc += rows[:, k]
    cols = acc.reshape(h, 2, w, cell, 2)
    out: NDArray[Any] = (
        np.add(cols[:, :, :, 0, :], cols[:, :, :, 1, :]) if cell > 1 else cols[:, :, :, 0, :]
    )
    for k in range(2, cell):
        out += cols[:, :, :, k, :]
    return out


def grey_world_gains(rgb: NDArray[np.float32], *, black: float = 0.0) -> NDArray[np.float32]:
    """Per-colour gains that make the frame's mean grey (green kept), within 1/4..4."""
    means = rgb.reshape(-1, 3).mean(axis=0) - black
    means = np.maximum(means, 1e-6)
    gains = means[1] / means
    return np.clip(gains, *WB_GAIN_LIMITS).astype(np.float32)


def _gamma_lut() -> NDArray[np.uint8]:
    x = np.linspace(0.0, 1.0, 2**_LUT_BITS, dtype=np.float64)
    return np.round(255 * x**_GAMMA).astype(np.uint8)


_LUT = _gamma_lut()


def tone(values: NDArray[np.float32], full_scale: float) -> NDArray[np.uint8]:
    """Linear values 0..full_scale to gamma-encoded 8-bit (values beyond are clipped)."""
    top = 2**_LUT_BITS - 1
    index = np.clip(values * (top / full_scale), 0, top).astype(np.uint16)
    out: NDArray[np.uint8] = _LUT[index]
    return out


def palette_lut(stops: tuple[str, ...] = PALETTE, size: int = 256) -> NDArray[np.uint8]:
    """(size, 3) uint8 colours interpolated linearly between the palette's stops."""
    anchors = np.array([[int(s[i : i + 2], 16) for i in (1, 3, 5)] for s in stops], float)
    at = np.linspace(0, len(stops) - 1, size)
    lut = np.stack([np.interp(at, np.arange(len(stops)), anchors[:, k]) for k in range(3)], -1)
    return np.round(lut).astype(np.uint8)


_PALETTE_LUT = palette_lut()


@dataclass(frozen=True)
class Preview:
    """An 8-bit RGB preview and what it shows.

    Attributes
    ----------
    rgb
        (H, W, 3) uint8.
    wb_gains
        Red, green, blue gains applied for white balance (Bayer frames), else None.
    temperature_c
        (low, high) °C at the palette's ends (thermal frames), else None.
    """

    rgb: NDArray[np.uint8]
    wb_gains: tuple[float, float, float] | None = None
    temperature_c: tuple[float, float] | None = None


def preview_rgb(
    image: NDArray[np.uint16],
    *,
    factor: int,
    bayer: str | None,
    bits: int,
    white_balance: bool = True,
) -> Preview:
    """A colour (Bayer) or grey (mono) preview of a raw frame.

    Parameters
    ----------
    image
        2-D 16-bit frame.
    factor
        Reduction, one of 1, 2, 4, 8.
    bayer
        Bayer order of the first pixel (after flips), or None for a mono sensor.
    bits
        Significant bits of the pixel values (full scale ``2**bits - 1``).
    white_balance
        Grey-world white balance of Bayer frames.
    """
    full_scale = float(2**bits - 1)
    if bayer is None:
        _check(image, factor)
        grey = tone(_block_mean(image, factor), full_scale)
        return Preview(np.repeat(grey[:, :, None], 3, axis=2))
    _check(image, factor)
    where = _positions(bayer)
    cell = max(factor // 2, 1)
    sums = _cell_sums(image, cell, bits=bits)
    planes = []
    for colour in "RGB":
        sites = [sums[:, r, :, c] for r, c in where[colour]]
        # Mean of a plane, in pixel units: sum / (cell² · sites).
        planes.append((sites, 1.0 / (cell * cell * len(sites))))
    means = np.array(
        [sum(float(p.mean()) for p in sites) * norm for sites, norm in planes], np.float64
    )
    gains = (
        np.clip(means[1] / np.maximum(means, 1e-6), *WB_GAIN_LIMITS)
        if white_balance
        else np.ones(3)
    )
    top = 2**_LUT_BITS - 1
    h, w = sums.shape[0], sums.shape[2]
    out = np.empty((h, w, 3), np.uint8)
    for k, (sites, norm) in enumerate(planes):
        total = sites[0] if len(sites) == 1 else sites[0].astype(np.uint32) + sites[1]
        index = total.astype(np.float32)
        index *= np.float32(gains[k] * norm * top / full_scale)
        np.minimum(index, top, out=index)
        out[:, :, k] = _LUT[index.astype(np.uint16)]
    if factor == 1:
        out = out.repeat(2, axis=0).repeat(2, axis=1)
    return Preview(out, wb_gains=(float(gains[0]), 1.0, float(gains[2])))


def thermal_rgb(
    image: NDArray[np.uint16],
    *,
    kelvin_per_count: float,
    factor: int = 1,
    low_c: float | None = None,
    high_c: float | None = None,
) -> Preview:
    """False colour of a radiometric (TLinear) frame between two temperatures.

    Parameters
    ----------
    image
        2-D frame whose counts are scene temperatures in ``kelvin_per_count`` units.
    kelvin_per_count
        0.01 or 0.1 (the Lepton's TLinear resolution).
    factor
        Reduction, one of 1, 2, 4, 8.
    low_c, high_c
        Temperatures at the palette's ends; each one not given is the frame's 1st
        (low) or 99th (high) percentile.
    """
    _check(image, factor)
    celsius = _block_mean(image, factor) * np.float32(kelvin_per_count) - np.float32(KELVIN_C)
    if low_c is None or high_c is None:
        p_low, p_high = np.percentile(celsius, (1, 99))
        low_c = float(p_low) if low_c is None else low_c
        high_c = float(p_high) if high_c is None else high_c
    if not high_c > low_c:
        high_c = low_c + 0.1  # a uniform scene: a span of 0.1 °C keeps the palette defined
    top = len(_PALETTE_LUT) - 1
    index = np.clip((celsius - low_c) * (top / (high_c - low_c)), 0, top).astype(np.uint8)
    return Preview(_PALETTE_LUT[index], temperature_c=(round(low_c, 2), round(high_c, 2)))


def encode_jpeg(rgb: NDArray[np.uint8], *, quality: int = 80) -> bytes:
    """Baseline JPEG of an (H, W, 3) uint8 image."""
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"an (H, W, 3) uint8 image, not {rgb.shape} {rgb.dtype}")
    out = io.BytesIO()
    Image.fromarray(rgb, "RGB").save(out, "JPEG", quality=quality)
    return out.getvalue()


def histogram(image: NDArray[np.uint16], *, bayer: str | None, bits: int) -> dict[str, Any]:
    """Counts of raw values per colour in 64 equal bins over 0..2**bits, with the clipped pixels.

    Returns
    -------
    dict
        ``full_scale`` (2**bits - 1), ``bin_width`` (values per bin), ``bins`` (64) and
        ``channels``: for each colour (``R``, ``G``, ``B``; ``Y`` for mono) its ``counts``,
        ``clipped_high`` (pixels at full scale or above) and ``clipped_low`` (pixels at 0).
    """
    if not 6 <= bits <= 16:
        raise ValueError(f"bits={bits}; allowed 6..16")
    full_scale = 2**bits - 1
    shift = bits - HISTOGRAM_BINS.bit_length() + 1
    if bayer is None:
        groups = {"Y": [image]}
    else:
        where = _positions(bayer)
        groups = {c: [image[r::2, k::2] for r, k in where[c]] for c in "RGB"}
    channels = {}
    for colour, parts in groups.items():
        counts = np.zeros(HISTOGRAM_BINS, np.int64)
        high = low = 0
        for part in parts:
            binned = np.minimum(part >> shift, HISTOGRAM_BINS - 1).ravel()
            counts += np.bincount(binned, minlength=HISTOGRAM_BINS)
            high += int(np.count_nonzero(part >= full_scale))
            low += int(np.count_nonzero(part == 0))
        channels[colour] = {"counts": counts.tolist(), "clipped_high": high, "clipped_low": low}
    return {
        "full_scale": full_scale,
        "bin_width": 1 << shift,
        "bins": HISTOGRAM_BINS,
        "channels": channels,
    }


def _check(image: NDArray[Any], factor: int) -> None:
    if factor not in FACTORS:
        raise ValueError(f"reduction {factor}; allowed {', '.join(map(str, FACTORS))}")
    if image.ndim != 2:
        raise ValueError(f"a 2-D frame, not shape {image.shape}")
    if image.shape[0] < 2 * factor or image.shape[1] < 2 * factor:
        raise ValueError(f"frame {image.shape} too small for a 1/{factor} preview")
