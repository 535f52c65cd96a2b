"""Streamed baseline TIFF: one 16-bit page per frame, written front to back.

tifffile's writer seeks back to link pages, so it needs the whole file in memory or on
disk. Here every page is laid out as IFD, description, pixels, and the offset of the next
IFD is known when the page is written (it follows this page's pixels; 0 for the last
page), so a burst is sent page by page and the pixel buffer goes out without a copy.
The result is a plain little-endian TIFF (one strip per page, uncompressed, minisblack)
that tifffile and ImageJ/Fiji read as a stack; each page's ImageDescription is the frame's
JSON metadata. A classic TIFF's offsets are 32-bit: a file holds less than 4 GiB, and
`largest_count` tells how many pages of a size fit, so that a burst that would not fit is
refused before its first byte.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterator
from typing import Any

import numpy as np

_SHORT, _ASCII, _LONG = 3, 2, 4
_TAGS = 12
_IFD_BYTES = 2 + 12 * _TAGS + 4
#: The largest classic TIFF: every offset, the end of the last page included, is 32-bit.
TIFF_LIMIT_BYTES = 2**32 - 1
#: An ImageDescription (a frame's JSON metadata) is assumed at most this long when a
#: burst's size is judged before its frames exist; real ones are about 1 KB.
DESCRIPTION_BOUND_BYTES = 4096


def _even(n: int) -> int:
    return n + (n & 1)


def header() -> bytes:
    """Byte order mark, magic number, and the first IFD right after (offset 8)."""
    return b"II*\x00" + struct.pack("<I", 8)


def page(
    image: np.ndarray, metadata: dict[str, Any], *, offset: int, last: bool
) -> tuple[bytes, memoryview, int]:
    """One page starting at file offset ``offset`` (even).

    Returns
    -------
    head
        IFD and ImageDescription (padded to an even length).
    pixels
        The image bytes, little-endian uint16.
    end
        File offset after the page (where the next page starts).
    """
    if image.ndim != 2:
        raise ValueError(f"a TIFF page takes a 2-D image, not shape {image.shape}")
    pixels = np.ascontiguousarray(image, dtype="<u2")
    height, width = pixels.shape
    description = json.dumps(metadata, separators=(",", ":")).encode("ascii") + b"\x00"
    desc_at = offset + _IFD_BYTES
    strip_at = _even(desc_at + len(description))
    nbytes = pixels.nbytes
    end = _even(strip_at + nbytes)
    entries = (
        (254, _LONG, 1, 0),  # NewSubfileType
        (256, _LONG, 1, width),
        (257, _LONG, 1, height),
        (258, _SHORT, 1, 16),  # BitsPerSample
        (259, _SHORT, 1, 1),  # Compression: none
        (262, _SHORT, 1, 1),  # Photometric: minisblack
        (270, _ASCII, len(description), desc_at),  # ImageDescription
        (273, _LONG, 1, strip_at),  # StripOffsets
        (277, _SHORT, 1, 1),  # SamplesPerPixel
        (278, _LONG, 1, height),  # RowsPerStrip
        (279, _LONG, 1, nbytes),  # StripByteCounts
        (339, _SHORT, 1, 1),  # SampleFormat: unsigned
    )
    if end >= 1 << 32:
        raise ValueError("burst too large for a classic TIFF (4 GiB)")
    ifd = bytearray(struct.pack("<H", len(entries)))
    for tag, kind, count, value in entries:
        packed = struct.pack("<HH", value, 0) if kind == _SHORT else struct.pack("<I", value)
        ifd += struct.pack("<HHI", tag, kind, count) + packed
    ifd += struct.pack("<I", 0 if last else end)
    head = bytes(ifd) + description + b"\x00" * (strip_at - desc_at - len(description))
    return head, pixels.data.cast("B"), end


def largest_count(width: int, height: int) -> int:
    """How many 16-bit pages of ``width`` x ``height`` pixels one classic TIFF holds.

    Each page is counted with its IFD, a description of `DESCRIPTION_BOUND_BYTES` and
    the padding to an even offset, after the 8-byte header.
    """
    if width < 1 or height < 1:
        raise ValueError(f"a page of {width}x{height} pixels; allowed: at least 1x1")
    page_bytes = _even(_IFD_BYTES + DESCRIPTION_BOUND_BYTES) + _even(width * height * 2)
    return (TIFF_LIMIT_BYTES - 8) // page_bytes


def stream(
    frames: Iterator[tuple[np.ndarray, dict[str, Any]]], count: int
) -> Iterator[bytes | memoryview]:
    """Chunks of a TIFF of ``count`` pages, produced as the frames arrive."""
    yield header()
    offset = 8
    for index, (image, metadata) in enumerate(frames):
        chunks, offset = page_chunks(image, metadata, offset=offset, last=index == count - 1)
        yield from chunks
        if index == count - 1:
            return


def page_chunks(
    image: np.ndarray, metadata: dict[str, Any], *, offset: int, last: bool
) -> tuple[list[bytes | memoryview], int]:
    """The chunks of one page written at ``offset``, padding included, and where it ends."""
    head, pixels, end = page(image, metadata, offset=offset, last=last)
    chunks: list[bytes | memoryview] = [head, pixels]
    pad = end - offset - len(head) - pixels.nbytes
    if pad:
        chunks.append(b"\x00" * pad)
    return chunks, end


def single(image: np.ndarray, metadata: dict[str, Any]) -> tuple[list[bytes | memoryview], int]:
    """The chunks of a one-page TIFF and its total length (for Content-Length)."""
    chunks, end = page_chunks(image, metadata, offset=8, last=True)
    return [header(), *chunks], end


def encode(image: np.ndarray, metadata: dict[str, Any]) -> bytes:
    """A whole one-page TIFF in memory (small images, tests)."""
    return b"".join(bytes(c) for c in stream(iter([(image, metadata)]), 1))
