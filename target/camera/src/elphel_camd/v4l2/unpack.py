"""Raw V4L2 frames to 16-bit images: unpacked 8/16-bit lines and CSI-2 packed RAW10/RAW12.

Each function reads a frame as the driver left it (lines ``stride`` bytes apart, padding
ignored) and writes its pixels into a ``(height, width)`` uint16 array, values in the low
bits as the sensor gave them. Packed data is unpacked with whole-frame NumPy operations:
the high bytes in one pass, the low bits of each group through a 256-entry table.
"""

from __future__ import annotations

import mmap

import numpy as np
from numpy.typing import NDArray

from elphel_camd.v4l2.formats import Packing, RawFormat

FrameData = bytes | bytearray | memoryview | mmap.mmap | NDArray[np.uint8]


# Rows unpacked at a time: the intermediate words of a block stay in the CPU's cache.
BLOCK_ROWS = 16

# A packed group as a record: the high bytes as one little-endian word, then the low bits.
_RAW10_GROUP = np.dtype([("high", "<u4"), ("low", "u1")])
_RAW12_GROUP = np.dtype([("high", "<u2"), ("low", "u1")])


def _raw10_low_table() -> NDArray[np.uint64]:
    """By RAW10's fifth byte (DDCCBBAA), a word with pixel k's 2 low bits at bit 16k."""
    codes = np.arange(256, dtype=np.uint64)
    table = np.zeros(256, dtype=np.uint64)
    for k in range(4):
        table |= ((codes >> np.uint64(2 * k)) & np.uint64(3)) << np.uint64(16 * k)
    return table


_RAW10_LOW = _raw10_low_table()


def frame_bytes(data: FrameData, *, height: int, stride: int) -> NDArray[np.uint8]:
    """The frame's bytes as ``(height, stride)`` lines (a view, no copy)."""
    flat = np.frombuffer(data, dtype=np.uint8)
    need = height * stride
    if flat.size < need:
        raise ValueError(
            f"frame buffer holds {flat.size} bytes; {height} lines of {stride} bytes need {need}"
        )
    return flat[:need].reshape(height, stride)


def unpack(
    data: FrameData,
    fmt: RawFormat,
    *,
    width: int,
    height: int,
    stride: int,
    out: NDArray[np.uint16] | None = None,
) -> NDArray[np.uint16]:
    """A raw frame's pixels as a ``(height, width)`` uint16 image.

    Parameters
    ----------
    data
        The frame as the driver wrote it (a mapped buffer, bytes, an array).
    fmt
        Its pixel format.
    width, height
        Frame size in pixels.
    stride
        Bytes from one line to the next (``bytesperline``; at least a line's bytes).
    out
        Where to write the pixels (C-contiguous ``(height, width)`` uint16); a new array
        if None.

    Returns
    -------
    numpy.ndarray
        ``out`` (or the new array) holding the pixels.
    """
    line = fmt.line_bytes(width)
    if stride < line:
        raise ValueError(f"stride {stride} bytes is shorter than a line of {width} pixels ({line})")
    if width % fmt.pixels_per_group:
        raise ValueError(
            f"width {width} of {fmt.fourcc!r} must be a multiple of {fmt.pixels_per_group}"
        )
    if out is None:
        out = np.empty((height, width), dtype=np.uint16)
    elif out.shape != (height, width) or out.dtype != np.uint16 or not out.flags.c_contiguous:
        raise ValueError(
            f"out must be a C-contiguous ({height}, {width}) uint16 array, "
            f"got {out.shape} {out.dtype}"
        )
    lines = frame_bytes(data, height=height, stride=stride)
    if fmt.packing is Packing.BYTE:
        np.copyto(out, lines[:, :line])
    elif fmt.packing is Packing.WORD:
        out[...] = lines[:, :line].view("<u2")  # little-endian on any host
    else:
        _unpack_packed(lines.reshape(-1), fmt, stride, out)
    return out


def _groups(
    flat: NDArray[np.uint8], dtype: np.dtype, *, first_row: int, rows: int, groups: int, stride: int
) -> NDArray[np.void]:
    """Packed groups of ``rows`` lines as records (a view of the frame's bytes)."""
    return np.ndarray(
        (rows, groups),
        dtype=dtype,
        buffer=flat,
        offset=first_row * stride,
        strides=(stride, dtype.itemsize),
    )


def _unpack_packed(
    flat: NDArray[np.uint8], fmt: RawFormat, stride: int, out: NDArray[np.uint16]
) -> None:
    """CSI-2 packed lines into ``out``, a block of rows at a time.

    A group's high bytes are read as one little-endian word, spread into 16-bit lanes
    (each byte moves to the low byte of its lane), shifted up by the low bits' width and
    completed by OR-ing the low bits spread the same way.
    """
    height, width = out.shape
    per_group = fmt.pixels_per_group
    word = np.dtype("<u8") if per_group == 4 else np.dtype("<u4")
    for first in range(0, height, BLOCK_ROWS):
        rows = min(BLOCK_ROWS, height - first)
        dtype = _RAW10_GROUP if per_group == 4 else _RAW12_GROUP
        groups = _groups(
            flat, dtype, first_row=first, rows=rows, groups=width // per_group, stride=stride
        )
        block = out[first : first + rows]
        words = (
            block.view(word.newbyteorder("=")) if np.little_endian else np.empty(groups.shape, word)
        )
        np.copyto(words, groups["high"], casting="unsafe")
        if per_group == 4:
            _raw10_words(words, groups["low"])
        else:
            _raw12_words(words, groups["low"])
        if not np.little_endian:
            block[...] = words.view("<u2").reshape(block.shape)


def _raw10_words(words: NDArray[np.uint64], low: NDArray[np.uint8]) -> None:
    spread = words << np.uint64(16)
    words |= spread
    words &= np.uint64(0x0000FFFF0000FFFF)
    np.left_shift(words, np.uint64(8), out=spread)
    words |= spread
    words &= np.uint64(0x00FF00FF00FF00FF)
    words <<= np.uint64(2)
    words |= _RAW10_LOW.take(low)


def _raw12_words(words: NDArray[np.uint32], low: NDArray[np.uint8]) -> None:
    words |= words << np.uint32(8)
    words &= np.uint32(0x00FF00FF)
    words <<= np.uint32(4)
    nibbles = low.astype(np.uint32)
    nibbles |= nibbles << np.uint32(12)
    nibbles &= np.uint32(0x000F000F)
    words |= nibbles
