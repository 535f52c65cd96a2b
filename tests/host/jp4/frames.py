"""Hand-built frames for the decoder's tests: Exif blocks, JPEGs and TIFFs, byte by byte.

Written independently of both the simulator's encoder and the host's parser, so a test
that feeds one of these pins the wire format, not one implementation against itself.
"""

from __future__ import annotations

import io
import struct

import numpy as np
from PIL import Image

ASCII, SHORT, LONG, RATIONAL, UNDEFINED = 2, 3, 4, 5, 7
_FORMAT = {SHORT: "H", LONG: "I", RATIONAL: "II"}


def ifd(entries: list[tuple[int, int, object]], start: int, order: str = ">") -> bytes:
    """An IFD at ``start``: (tag, type, values); values: str, bytes, or a tuple of ints."""
    raw = []
    for tag, kind, values in sorted(entries, key=lambda e: e[0]):
        if kind == ASCII:
            payload, count = str(values).encode() + b"\0", len(str(values)) + 1
        elif kind == UNDEFINED:
            payload, count = bytes(values), len(bytes(values))  # type: ignore[arg-type]
        else:
            vals = tuple(values)  # type: ignore[arg-type]
            count = len(vals) // 2 if kind == RATIONAL else len(vals)
            payload = struct.pack(f"{order}{_FORMAT[kind][0] * len(vals)}", *vals)
        raw.append((tag, kind, count, payload))
    data_at = start + 2 + 12 * len(raw) + 4
    head, tail = struct.pack(f"{order}H", len(raw)), b""
    for tag, kind, count, payload in raw:
        if len(payload) <= 4:
            field = payload.ljust(4, b"\0")
        else:
            field = struct.pack(f"{order}I", data_at + len(tail))
            tail += payload + b"\0" * (len(payload) % 2)
        head += struct.pack(f"{order}HHI", tag, kind, count) + field
    return head + b"\0\0\0\0" + tail


def tiff_structure(
    ifd0: list[tuple[int, int, object]],
    exif: list[tuple[int, int, object]] | None,
    order: str = ">",
    tail: bytes = b"",
) -> bytes:
    """A TIFF header, IFD0 (with an Exif IFD pointer when ``exif`` is given), the Exif IFD."""
    header = (b"MM\0\x2a" if order == ">" else b"II\x2a\0") + struct.pack(f"{order}I", 8)
    entries = list(ifd0)
    if exif is not None:
        size0 = len(ifd([*entries, (0x8769, LONG, (0,))], 8, order))
        entries.append((0x8769, LONG, (8 + size0,)))
        first = ifd(entries, 8, order)
        return header + first + ifd(exif, 8 + len(first), order) + tail
    return header + ifd(entries, 8, order) + tail


def maker_note(
    *, color_mode: int = 5, words: int = 16, gamma: int = 100, black: int = 0, flips: int = 0
) -> tuple[int, ...]:
    """Elphel MakerNote words: unit gains, one gamma word for all channels, 64x32 window."""
    mn = [0x10000] * 4 + [(black << 24) | (gamma << 16) | 0x400] * 4
    mn += [(64 << 16) | 0, (32 << 16) | 0, flips | (color_mode << 4), 0, 0, 100, 0, 0]
    return tuple(mn[:words])


def elphel_exif(note: tuple[int, ...] | None, *, frame: int = 9, when: str = "2024:05:06 07:08:09",
                subsec: str = "250000") -> bytes:  # fmt: skip
    """An NC393-style Exif block (without the ``Exif\\0\\0`` prefix)."""
    ifd0 = [(0x010F, ASCII, "Elphel"), (0x0110, ASCII, "NC393"), (0x9211, LONG, (frame,)),
            (0x0129, SHORT, (1, 4))]  # fmt: skip
    exif = [(0x829A, RATIONAL, (2500, 1_000_000)), (0x9003, ASCII, when),
            (0x9291, ASCII, subsec)]  # fmt: skip
    if note is not None:
        exif.append((0x927C, LONG, note))
    return tiff_structure(ifd0, exif)


def greyscale_jpeg(width: int = 64, height: int = 32, *, mode: str = "L") -> bytes:
    rng = np.random.default_rng(0)
    shape = (height, width) if mode == "L" else (height, width, 3)
    buf = io.BytesIO()
    Image.fromarray(rng.integers(0, 256, shape, dtype=np.uint8)).save(buf, "JPEG", quality=95)
    return buf.getvalue()


def with_exif(jpeg: bytes, block: bytes) -> bytes:
    """``jpeg`` with an APP1 Exif segment holding ``block`` right after its SOI."""
    payload = b"Exif\0\0" + block
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload + jpeg[2:]


def raw_tiff(pixels: np.ndarray, exif: list[tuple[int, int, object]] | None) -> bytes:
    """An uncompressed one-strip greyscale TIFF (8 or 16 bits), big-endian, optional Exif IFD."""
    h, w = pixels.shape
    bits = pixels.dtype.itemsize * 8
    data = pixels.astype(f">u{pixels.dtype.itemsize}").tobytes()

    def entries(offset: int) -> list[tuple[int, int, object]]:
        return [(256, LONG, (w,)), (257, LONG, (h,)), (258, SHORT, (bits,)), (259, SHORT, (1,)),
                (262, SHORT, (1,)), (273, LONG, (offset,)), (278, LONG, (h,)),
                (279, LONG, (len(data),))]  # fmt: skip

    size = len(tiff_structure(entries(0), exif))
    return tiff_structure(entries(size), exif, tail=data)
