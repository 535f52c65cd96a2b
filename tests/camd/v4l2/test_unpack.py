"""Raw frames to images: each layout against a packer written from the kernel's pixfmt pages."""

from __future__ import annotations

import numpy as np
import pytest

from elphel_camd.v4l2.formats import RAW_FORMATS, Packing, raw_format
from elphel_camd.v4l2.unpack import unpack


def _pack_line(pixels: np.ndarray, fourcc: str) -> bytes:
    """One line as the driver would write it, pixel by pixel (slow, plain)."""
    fmt = raw_format(fourcc)
    out = bytearray()
    values = [int(v) for v in pixels]
    if fmt.packing is Packing.BYTE:
        return bytes(values)
    if fmt.packing is Packing.WORD:
        for v in values:
            out += v.to_bytes(2, "little")
        return bytes(out)
    if fmt.bits == 10:  # bytes 0-3: high 8 bits of A-D; byte 4: DDCCBBAA
        for a, b, c, d in zip(*[iter(values)] * 4, strict=True):
            out += bytes([a >> 2, b >> 2, c >> 2, d >> 2])
            out.append((a & 3) | (b & 3) << 2 | (c & 3) << 4 | (d & 3) << 6)
        return bytes(out)
    for a, b in zip(*[iter(values)] * 2, strict=True):  # RAW12: high bytes, then BBBBAAAA
        out += bytes([a >> 4, b >> 4, (a & 0xF) | (b & 0xF) << 4])
    return bytes(out)


def _frame(image: np.ndarray, fourcc: str, pad: int) -> tuple[bytes, int]:
    lines = [_pack_line(row, fourcc) for row in image]
    stride = len(lines[0]) + pad
    return b"".join(line + b"\xa5" * pad for line in lines), stride


@pytest.mark.parametrize("fourcc", sorted(RAW_FORMATS))
@pytest.mark.parametrize("pad", [0, 12])
def test_every_raw_format_unpacks_to_the_pixels_it_was_packed_from(fourcc: str, pad: int) -> None:
    fmt = raw_format(fourcc)
    rng = np.random.default_rng(len(fourcc) + pad)
    height, width = 6, 24
    image = rng.integers(0, 1 << fmt.bits, (height, width), dtype=np.uint16)
    image[0, :4] = [0, (1 << fmt.bits) - 1, 1, (1 << fmt.bits) - 2]  # the extremes
    data, stride = _frame(image, fourcc, pad)
    got = unpack(data, fmt, width=width, height=height, stride=stride)
    np.testing.assert_array_equal(got, image)


def test_packed_frame_taller_than_one_block_and_written_into_a_given_array() -> None:
    fmt = raw_format("pBAA")
    rng = np.random.default_rng(7)
    image = rng.integers(0, 1024, (37, 40), dtype=np.uint16)  # 37 rows: blocks of 16 + 5
    data, stride = _frame(image, "pBAA", 3)
    out = np.zeros_like(image)
    got = unpack(np.frombuffer(data, np.uint8), fmt, width=40, height=37, stride=stride, out=out)
    assert got is out
    np.testing.assert_array_equal(out, image)


def test_a_buffer_shorter_than_its_lines_is_refused_with_both_sizes() -> None:
    with pytest.raises(ValueError, match="holds 99 bytes; 4 lines of 30 bytes need 120"):
        unpack(bytes(99), raw_format("pRAA"), width=24, height=4, stride=30)


def test_a_stride_shorter_than_a_line_is_refused() -> None:
    with pytest.raises(ValueError, match="stride 40 bytes is shorter than a line of 24 pixels"):
        unpack(bytes(400), raw_format("RG10"), width=24, height=4, stride=40)


def test_a_packed_width_that_splits_a_group_is_refused() -> None:
    with pytest.raises(ValueError, match="multiple of 4"):
        unpack(bytes(400), raw_format("pRAA"), width=22, height=2, stride=30)


def test_a_wrong_output_array_is_refused() -> None:
    with pytest.raises(ValueError, match=r"C-contiguous \(2, 8\) uint16"):
        unpack(bytes(32), raw_format("RG10"), width=8, height=2, stride=16, out=np.zeros((2, 8)))
