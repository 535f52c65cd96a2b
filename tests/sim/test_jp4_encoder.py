"""The simulator's JP4/JP46 encoder: gamma table, block layout, Exif and MakerNote words.

The layout is checked pixel by pixel against the formulas of the JP4/JP46 format (loops
on a small frame, independent of the encoder's reshapes); the Exif block is read back
with Pillow's own Exif reader, so neither side is checked against itself.
"""

import io
import struct

import numpy as np
import pytest
from PIL import Image

from elphel_sim.jp4 import (
    code_lut,
    encode_jp4,
    gamma_table,
    rearrange,
    site_channels,
)

T0 = 1_700_000_000_123_456_789


def test_gamma_table_linear_and_power() -> None:
    linear = gamma_table(1.0, 0.0, 0x400)
    assert linear.shape == (257,)
    assert linear[0] == 0 and linear[256] == 65535
    assert linear[128] == round(65535 * 0.5)
    g = gamma_table(0.57, 0.0, 0x400)
    assert g[64] == round(65535 * 0.25**0.57)
    black = gamma_table(1.0, 10 / 256, 0x400)
    assert black[:11].tolist() == [0] * 11
    assert black[138] == round(65535 * 128 / 246)
    doubled = gamma_table(1.0, 0.0, 0x800)
    assert doubled[128] == 65535 and doubled[64] == 2 * round(65535 * 0.25)


def test_code_lut_is_the_interpolated_high_byte() -> None:
    lut = code_lut(gamma_table(1.0, 0.0, 0x400))
    assert lut[0] == 0 and lut[65535] == 255
    assert lut[0x8000] == 128  # table[128] = round(32767.5) = 0x8000
    assert lut[0x80FF] == 128 and lut[0x7FFF] == 127
    lut57 = code_lut(gamma_table(0.57, 0.0, 0x400))
    assert lut57[0x1000] == int(65535 * (16 / 256) ** 0.57) >> 8
    assert np.all(np.diff(lut57.astype(int)) >= 0)


@pytest.mark.parametrize(
    ("fliph", "flipv", "bayer_mode", "cell"),
    [
        (0, 0, 0, [[1, 0], [3, 2]]),
        (1, 0, 0, [[0, 1], [2, 3]]),
        (0, 1, 0, [[3, 2], [1, 0]]),
        (1, 1, 0, [[2, 3], [0, 1]]),
        (0, 0, 1, [[0, 1], [2, 3]]),
        (0, 0, 2, [[3, 2], [1, 0]]),
        (1, 0, 1, [[1, 0], [3, 2]]),
    ],
)
def test_site_channels(fliph: int, flipv: int, bayer_mode: int, cell: list[list[int]]) -> None:
    assert site_channels(fliph, flipv, bayer_mode).tolist() == cell


def test_jp4_layout_matches_the_format() -> None:
    h, w = 32, 64
    mosaic = np.arange(h * w, dtype=np.uint32).reshape(h, w)
    out = rearrange(mosaic, 5)
    expected = np.empty_like(mosaic)
    for yb in range(h // 16):
        for xb in range(w // 16):
            row = 16 * yb + (0 if xb < w // 32 else 8)
            col = 32 * (xb if xb < w // 32 else xb - w // 32)
            for nb in range(4):
                for y in range(8):
                    for x in range(8):
                        src = mosaic[16 * yb + 2 * y + (nb >> 1), 16 * xb + 2 * x + (nb & 1)]
                        expected[row + y, col + 8 * nb + x] = src
    assert np.array_equal(out, expected)


def test_jp46_layout_matches_the_format() -> None:
    h, w = 32, 48
    mosaic = np.arange(h * w, dtype=np.uint32).reshape(h, w)
    out = rearrange(mosaic, 2)
    expected = np.empty_like(mosaic)
    for yb in range(h // 16):
        for xb in range(w // 16):
            for y in range(16):
                for x in range(16):
                    src = mosaic[16 * yb + 2 * (y % 8) + y // 8, 16 * xb + 2 * (x % 8) + x // 8]
                    expected[16 * yb + y, 16 * xb + x] = src
    assert np.array_equal(out, expected)
    assert np.array_equal(rearrange(mosaic, 0), mosaic)


def _frame() -> bytes:
    rng = np.random.default_rng(3)
    mosaic = rng.integers(0, 4096, (48, 64)).astype(np.uint16)
    return encode_jp4(
        mosaic,
        bits=12,
        frame=1234,
        timestamp_ns=T0,
        port=2,
        exposure_us=5000,
        quality=90,
        gamma=0.57,
        black=10 / 256,
        gamma_scale=0x400,
        gains=(0x10000, 0x18000, 0x20000, 0x28000),
        flips=(1, 0),
        bayer_mode=2,
        woi=(16, 32, 64, 48),
    )


def test_exif_read_back_by_pillow() -> None:
    data = _frame()
    assert data[:2] == b"\xff\xd8" and data[2:4] == b"\xff\xe1"
    image = Image.open(io.BytesIO(data))
    assert image.mode == "L" and image.size == (64, 48)
    exif = image.getexif()
    assert exif[0x010F] == "Elphel" and exif[0x0110] == "NC393"
    assert exif[0x9211] == 1234
    assert exif[0x0129][0] == 2
    sub = exif.get_ifd(0x8769)
    assert sub[0x9003] == "2023:11:14 22:13:20"
    assert sub[0x9291] == "123456"
    assert float(sub[0x829A]) == pytest.approx(0.005)
    note = sub[0x927C]
    assert len(note) == 16
    assert note[:4] == (0x10000, 0x18000, 0x20000, 0x28000)
    assert note[4:8] == ((10 << 24) | (57 << 16) | 0x400,) * 4
    assert note[8] == (64 << 16) | 16 and note[9] == (48 << 16) | 32
    assert note[10] == 1 | (2 << 2) | (5 << 4) | 0x111100  # decimation, binning 1
    assert note[13] & 0x7F == 90
    assert note[14] == note[15] == 0xFFFFFFFF


def test_maker_note_is_big_endian_longs() -> None:
    data = _frame()
    words = struct.pack(">4I", 0x10000, 0x18000, 0x20000, 0x28000)
    assert words in data


def test_pixels_are_the_gamma_codes_in_jp4_order() -> None:
    rng = np.random.default_rng(5)
    mosaic = rng.integers(0, 4096, (32, 64)).astype(np.uint16)
    data = encode_jp4(mosaic, bits=12, frame=1, timestamp_ns=T0, quality=100)
    pixels = np.asarray(Image.open(io.BytesIO(data)))
    codes = code_lut(gamma_table(1.0, 0.0, 0x400))[mosaic.astype(np.int64) * 16]
    diff = pixels.astype(int) - rearrange(codes, 5).astype(int)
    assert np.abs(diff).max() <= 1  # quality 100: the JPEG's own rounding


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"color_mode": 3}, "color_mode=3"),
        ({"shape": (32, 48)}, "multiple of 32"),
        ({"shape": (24, 64)}, "multiple of 16"),
        ({"bits": 12, "value": 4096}, "outside 0..4095"),
        ({"gamma": 0.05}, "gamma=0.05"),
        ({"black": 1.0}, "black=1.0"),
        ({"quality": 0}, "quality=0"),
        ({"gamma": (1.0, 1.0)}, "four"),
    ],
)
def test_bad_arguments(kwargs: dict, message: str) -> None:
    shape = kwargs.pop("shape", (32, 64))
    value = kwargs.pop("value", 0)
    kwargs.setdefault("bits", 12)
    mosaic = np.full(shape, value, dtype=np.uint16)
    with pytest.raises(ValueError, match=message.replace(".", r"\.").replace("(", r"\(")):
        encode_jp4(mosaic, frame=1, timestamp_ns=T0, **kwargs)
