"""The simulated NC393's compressor: a Bayer frame to an Elphel JP4/JP46 file.

`encode_jp4` does what a stock NC393 does between the sensor and imgsrv: each linear
sample goes through its Bayer channel's 257-entry gamma table (linear interpolation,
high byte kept), the 8-bit mosaic is rearranged so that every 8x8 DCT block holds one
colour (JP4, COLOR_MODE 5) or one Bayer site (JP46, COLOR_MODE 2), compressed as an
8-bit greyscale baseline JPEG (Pillow), and an APP1 Exif block carries the frame number,
port, time, exposure and Elphel's 16-word MakerNote. This is the simulator's own code;
the host's decoder (elphel_host.camera.jp4) is written separately, so a round trip
through both checks both.
"""

from __future__ import annotations

import io
import struct
from collections.abc import Sequence
from datetime import UTC, datetime

import numpy as np
from numpy.typing import NDArray
from PIL import Image

JP4 = 5
JP46 = 2
MONO = 0
COLOR_MODES = (MONO, JP46, JP4)

# Gamma channel (0 red, 1 green of red rows, 2 green of blue rows, 3 blue) of each site
# of the 2x2 cell, unflipped and BAYER_MODE 0: G R / B G.
_SITE_CHANNEL = np.array([[1, 0], [3, 2]])

_ASCII, _SHORT, _LONG, _RATIONAL = 2, 3, 4, 5


def gamma_table(gamma: float, black: float, scale: int) -> NDArray[np.int64]:
    """The camera's 257-entry gamma table of one channel (entries 0..0xFFFF).

    Entry i is ``round(65535 * x**gamma) * scale / 0x400`` clipped at 0xFFFF, with
    ``x = (i - 256 black) / (256 - 256 black)`` clipped below at 0; gamma is clamped to
    [0.13, 10] as the camera does.
    """
    g = min(max(gamma, 0.13), 10.0)
    i = np.arange(257, dtype=np.float64)
    x = np.clip((i - 256.0 * black) / (256.0 - 256.0 * black), 0.0, None)
    table = np.round(65535.0 * x**g) * scale / 0x400
    return np.minimum(np.floor(table), 0xFFFF).astype(np.int64)


def code_lut(table: NDArray[np.int64]) -> NDArray[np.uint8]:
    """8-bit code of every 16-bit linear sample: the interpolated table's high byte."""
    v = np.arange(65536, dtype=np.int64)
    i, f = v >> 8, v & 0xFF
    t = table[i] + (((table[i + 1] - table[i]) * f) >> 8)
    return np.clip(t >> 8, 0, 255).astype(np.uint8)


def _per_channel(value: float | Sequence[float], name: str) -> tuple[float, ...]:
    values = tuple(value) if isinstance(value, Sequence) else (value,) * 4
    if len(values) != 4:
        raise ValueError(f"{name}={value!r}; allowed: one value or four (R, Gr, Gb, B)")
    return tuple(float(v) for v in values)


def site_channels(fliph: int, flipv: int, bayer_mode: int) -> NDArray[np.intp]:
    """Gamma channel of each site of the read-out 2x2 cell, after flips and BAYER_MODE."""
    h = (fliph & 1) ^ (bayer_mode & 1)
    v = (flipv & 1) ^ ((bayer_mode >> 1) & 1)
    out: NDArray[np.intp] = _SITE_CHANNEL[np.ix_([v, 1 - v], [h, 1 - h])]
    return out


def rearrange(codes: NDArray[np.uint8], color_mode: int) -> NDArray[np.uint8]:
    """Lay an 8-bit mosaic out as the JPEG's pixels for JP4 or JP46 (mono: unchanged)."""
    h, w = codes.shape
    if color_mode == JP4:
        # mosaic [yb, y, dy, half, xq, x, dx] -> jpeg [yb, half, y, xq, dy, dx, x]
        m = codes.reshape(h // 16, 8, 2, 2, w // 32, 8, 2)
        return np.ascontiguousarray(m.transpose(0, 3, 1, 4, 2, 6, 5)).reshape(h, w)
    if color_mode == JP46:
        # mosaic [yb, y, qy, xb, x, qx] -> jpeg [yb, qy, y, xb, qx, x]
        m = codes.reshape(h // 16, 8, 2, w // 16, 8, 2)
        return np.ascontiguousarray(m.transpose(0, 2, 1, 3, 5, 4)).reshape(h, w)
    return codes


def _check_shape(shape: tuple[int, ...], color_mode: int) -> None:
    if len(shape) != 2:
        raise ValueError(f"mosaic must be 2-D (H, W), got shape {shape}")
    h, w = shape
    need_w = {JP4: 32, JP46: 16}.get(color_mode, 1)
    need_h = 16 if color_mode in (JP4, JP46) else 1
    if w % need_w or h % need_h or not w or not h:
        raise ValueError(
            f"mosaic {w}x{h}; COLOR_MODE {color_mode} needs the width a multiple of "
            f"{need_w} and the height a multiple of {need_h}"
        )


def _ifd(entries: list[tuple[int, int, int, bytes]], start: int) -> bytes:
    """One big-endian IFD at offset ``start``, its out-of-line values right after it."""
    entries = sorted(entries)
    data_at = start + 2 + 12 * len(entries) + 4
    head, data = [struct.pack(">H", len(entries))], b""
    for tag, kind, count, payload in entries:
        if len(payload) <= 4:
            field = payload.ljust(4, b"\0")
        else:
            field = struct.pack(">I", data_at + len(data))
            data += payload + b"\0" * (len(payload) % 2)
        head.append(struct.pack(">HHI", tag, kind, count) + field)
    return b"".join(head) + b"\0\0\0\0" + data


def _ascii(text: str) -> tuple[int, bytes]:
    raw = text.encode("ascii") + b"\0"
    return len(raw), raw


def exif_block(
    *,
    frame: int,
    port: int,
    timestamp_ns: int,
    exposure_us: int,
    maker_note: Sequence[int],
    model: str = "NC393",
) -> bytes:
    """The APP1 payload an NC393 frame carries: "Exif", two zero bytes, a big-endian TIFF."""
    when = datetime.fromtimestamp(timestamp_ns // 1_000_000_000, tz=UTC)
    stamp = when.strftime("%Y:%m:%d %H:%M:%S")
    usec = (timestamp_ns // 1000) % 1_000_000
    ifd0: list[tuple[int, int, int, bytes]] = [
        (0x010F, _ASCII, *_ascii("Elphel")),
        (0x0110, _ASCII, *_ascii(model)),
        (0x0131, _ASCII, *_ascii("elphel-sim")),
        (0x0132, _ASCII, *_ascii(stamp)),
        (0x0129, _SHORT, 2, struct.pack(">HH", port, 4)),
        (0x9211, _LONG, 1, struct.pack(">I", frame & 0xFFFFFFFF)),
    ]
    exif_ptr = (0x8769, _LONG, 1, b"\0\0\0\0")
    size0 = len(_ifd([*ifd0, exif_ptr], 8))
    exif_at = 8 + size0
    first = _ifd([*ifd0, (0x8769, _LONG, 1, struct.pack(">I", exif_at))], 8)
    note = struct.pack(f">{len(maker_note)}I", *(v & 0xFFFFFFFF for v in maker_note))
    sub = f"{usec:06d}".encode("ascii") + b"\0"
    exif = _ifd(
        [
            (0x829A, _RATIONAL, 1, struct.pack(">II", exposure_us, 1_000_000)),
            (0x9003, _ASCII, *_ascii(stamp)),
            (0x9291, _ASCII, len(sub), sub),
            (0x927C, _LONG, len(maker_note), note),
        ],
        exif_at,
    )
    return b"Exif\0\0" + b"MM\0\x2a" + struct.pack(">I", 8) + first + exif


def maker_note(
    *,
    gains: Sequence[int],
    gamma: Sequence[float],
    black: Sequence[float],
    gamma_scale: Sequence[int],
    woi: tuple[int, int, int, int],
    flips: tuple[int, int],
    bayer_mode: int,
    color_mode: int,
    quality: int,
    decimation: tuple[int, int] = (1, 1),
    binning: tuple[int, int] = (1, 1),
) -> list[int]:
    """Elphel's 16-word MakerNote (gains, gamma words, window, mode, quality, no temperatures)."""
    words = [int(g) & 0xFFFFFFFF for g in gains]
    for g, b, s in zip(gamma, black, gamma_scale, strict=True):
        words.append((round(b * 256) << 24) | (round(g * 100) << 16) | int(s))
    left, top, width, height = woi
    words.append((width << 16) | left)
    words.append((height << 16) | top)
    mode = (flips[0] & 1) | (flips[1] & 1) << 1 | (bayer_mode & 3) << 2 | color_mode << 4
    mode |= (decimation[0] & 0xF) << 8 | (decimation[1] & 0xF) << 12
    mode |= (binning[0] & 0xF) << 16 | (binning[1] & 0xF) << 20
    words.append(mode)
    words += [0, 0, quality & 0x7F, 0xFFFFFFFF, 0xFFFFFFFF]
    return words


def encode_jp4(
    mosaic: NDArray[np.uint16],
    *,
    bits: int,
    frame: int,
    timestamp_ns: int,
    port: int = 0,
    exposure_us: int = 1000,
    color_mode: int = JP4,
    quality: int = 100,
    gamma: float | Sequence[float] = 1.0,
    black: float | Sequence[float] = 0.0,
    gamma_scale: int | Sequence[int] = 0x400,
    gains: Sequence[int] = (0x10000,) * 4,
    flips: tuple[int, int] = (0, 0),
    bayer_mode: int = 0,
    woi: tuple[int, int, int, int] | None = None,
    decimation: tuple[int, int] = (1, 1),
    binning: tuple[int, int] = (1, 1),
    model: str = "NC393",
) -> bytes:
    """Compress one read-out Bayer frame into the JPEG file a stock NC393's imgsrv serves.

    Parameters
    ----------
    mosaic
        The frame as the sensor read it out (flips applied), (H, W) unsigned integers of
        ``bits`` (8..16) significant bits, scaled to 16 bits before the gamma table.
    frame, timestamp_ns, port, exposure_us, model
        Exif ImageNumber, DateTimeOriginal + SubSecTimeOriginal (UTC, microseconds),
        PageNumber, ExposureTime and Model.
    color_mode, quality
        5 JP4, 2 JP46, 0 mono (greyscale JPEG of the gamma-coded frame as it is); JPEG
        quality 1..100 (also in MakerNote word 13).
    gamma, black, gamma_scale
        Each one value or four (channels R, Gr, Gb, B): gamma in steps of 0.01
        (0.13..2.55), black level in steps of 1/256 of full scale (0..255/256), gamma
        scale with 0x400 = 1.0.
    flips, bayer_mode
        (FLIPH, FLIPV) and BAYER_MODE: which gamma channel each site of the cell uses
        (G R / B G unflipped), and recorded in the MakerNote.
    gains, woi, decimation, binning
        Recorded in the MakerNote only: GAINR, GAING, GAINGB, GAINB (16.16, applied by
        the sensor); (WOI_LEFT, WOI_TOP, WOI_WIDTH, WOI_HEIGHT), default (0, 0, W, H);
        (DCM_HOR, DCM_VERT) and (BIN_HOR, BIN_VERT), 1..15.

    Raises
    ------
    ValueError
        Shape, depth or a value outside what the MakerNote can hold.
    """
    gammas, blacks, scales = check_encoding(
        mosaic, bits, color_mode, quality, gamma=gamma, black=black, gamma_scale=gamma_scale
    )
    sites = site_channels(*flips, bayer_mode)
    codes = gamma_codes(mosaic, bits, list(zip(gammas, blacks, scales, strict=True)), sites)
    note = maker_note(
        gains=gains,
        gamma=gammas,
        black=blacks,
        gamma_scale=scales,
        woi=woi or (0, 0, mosaic.shape[1], mosaic.shape[0]),
        flips=flips,
        bayer_mode=bayer_mode,
        color_mode=color_mode,
        quality=quality,
        decimation=decimation,
        binning=binning,
    )
    head = file_head(
        frame=frame,
        port=port,
        timestamp_ns=timestamp_ns,
        exposure_us=exposure_us,
        note=note,
        model=model,
    )
    jpeg = jpeg_bytes(rearrange(codes, color_mode), quality)
    return head + jpeg[2:]


def file_head(
    *,
    frame: int,
    port: int,
    timestamp_ns: int,
    exposure_us: int,
    note: Sequence[int],
    model: str = "NC393",
) -> bytes:
    """The first bytes of a frame's file: the JPEG's start marker and the APP1 Exif segment.

    They depend on the frame's number, port, time, exposure, MakerNote (`maker_note`) and
    camera model only, not on its pixels: `encode_jp4`'s file starts with them.
    """
    app1 = exif_block(
        frame=frame,
        port=port,
        timestamp_ns=timestamp_ns,
        exposure_us=exposure_us,
        maker_note=note,
        model=model,
    )
    return b"\xff\xd8\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1


def check_encoding(
    mosaic: NDArray[np.uint16],
    bits: int,
    color_mode: int,
    quality: int,
    *,
    gamma: float | Sequence[float],
    black: float | Sequence[float],
    gamma_scale: int | Sequence[int],
) -> tuple[tuple[float, ...], tuple[float, ...], tuple[int, ...]]:
    """Check `encode_jp4`'s frame and settings; return gamma, black and scale per channel.

    Raises
    ------
    ValueError
        Shape, depth or a value outside what the MakerNote can hold.
    """
    if color_mode not in COLOR_MODES:
        raise ValueError(f"color_mode={color_mode}; allowed: 5 (JP4), 2 (JP46), 0 (mono)")
    _check_shape(mosaic.shape, color_mode)
    if not 8 <= bits <= 16:
        raise ValueError(f"bits={bits}; allowed: 8..16")
    if int(mosaic.max(initial=0)) >= 1 << bits or int(mosaic.min(initial=0)) < 0:
        raise ValueError(f"mosaic has samples outside 0..{(1 << bits) - 1} ({bits} bits)")
    if not 1 <= quality <= 100:
        raise ValueError(f"quality={quality}; allowed: 1..100")
    gammas = _per_channel(gamma, "gamma")
    blacks = _per_channel(black, "black")
    scales = tuple(int(s) for s in _per_channel(gamma_scale, "gamma_scale"))
    for g in gammas:
        if not 13 <= round(g * 100) <= 255:
            raise ValueError(f"gamma={g}; allowed: 0.13..2.55 in steps of 0.01")
    for b in blacks:
        if not 0 <= round(b * 256) <= 255:
            raise ValueError(f"black={b}; allowed: 0..255/256 in steps of 1/256")
    for s in scales:
        if not 0 < s <= 0xFFFF:
            raise ValueError(f"gamma_scale={s:#x}; allowed: 1..0xffff (0x400 = 1.0)")
    return gammas, blacks, scales


def gamma_codes(
    mosaic: NDArray[np.uint16],
    bits: int,
    curves: Sequence[tuple[float, float, int]],
    sites: NDArray[np.intp],
) -> NDArray[np.uint8]:
    """The 8-bit codes of ``mosaic`` through each site's gamma curve (gamma, black, scale).

    The camera's table is built from the MakerNote's quantised values.
    """
    luts = [
        code_lut(gamma_table(round(g * 100) / 100, round(b * 256) / 256, s)) for g, b, s in curves
    ]
    wide = mosaic.astype(np.uint16) << np.uint16(16 - bits)
    codes = np.empty(mosaic.shape, dtype=np.uint8)
    for dy in (0, 1):
        for dx in (0, 1):
            codes[dy::2, dx::2] = np.take(luts[sites[dy, dx]], wide[dy::2, dx::2])
    return codes


def jpeg_bytes(image: NDArray[np.uint8], quality: int) -> bytes:
    """``image`` as a greyscale JPEG file of ``quality``."""
    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="JPEG", quality=quality)
    return buf.getvalue()
