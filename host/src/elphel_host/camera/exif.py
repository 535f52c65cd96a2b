"""The parts of a JPEG and its Exif block that an Elphel frame's decoder reads.

`scan_jpeg` walks a JPEG's marker segments without decoding the image: it checks the
file is a whole baseline or progressive JPEG (start and end markers, every segment
inside the file) and returns the frame size, the number of components and the Exif
block of the APP1 segment. `read_exif` parses a TIFF structure (the Exif block, or an
uncompressed TIFF as imgsrv serves it) into the fields an NC393 frame carries: IFD0
ImageNumber and PageNumber, the Exif IFD's ExposureTime, DateTimeOriginal,
SubSecTimeOriginal and Elphel's MakerNote. Every error is a `Jp4FormatError` saying
what is wrong and where; callers prefix the file name or URL.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

from elphel_host.errors import Jp4FormatError

_EXIF_HEADER = b"Exif\0\0"
# SOFn markers carry the frame size; C4 (DHT), C8 (JPG) and CC (DAC) share the range.
_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
_STANDALONE = frozenset(range(0xD0, 0xD8)) | {0x01}
# TIFF field types: size of one value in bytes.
_TYPE_SIZE = {
    1: 1,
    2: 1,
    3: 2,
    4: 4,
    5: 8,
    6: 1,
    7: 1,
    8: 2,
    9: 4,
    10: 8,
    11: 4,
    12: 8,
    13: 4,
    16: 8,
}

TAG_PAGE_NUMBER = 0x0129
TAG_IMAGE_DESCRIPTION = 0x010E
TAG_MAKE = 0x010F
TAG_MODEL = 0x0110
TAG_EXIF_IFD = 0x8769
TAG_EXPOSURE_TIME = 0x829A
TAG_DATE_TIME_ORIGINAL = 0x9003
TAG_IMAGE_NUMBER = 0x9211
TAG_MAKER_NOTE = 0x927C
TAG_SUBSEC_TIME_ORIGINAL = 0x9291


@dataclass(frozen=True)
class JpegInfo:
    """What a JPEG's headers say: frame size, components and the Exif block (or None)."""

    width: int
    height: int
    components: int
    exif: bytes | None


def scan_jpeg(data: bytes) -> JpegInfo:
    """Check a JPEG's structure and read its frame header and Exif block.

    Raises
    ------
    Jp4FormatError
        Not a JPEG, a segment running past the end, no frame header, or no end marker
        after the scan data (a truncated file).
    """
    if data[:2] != b"\xff\xd8":
        raise Jp4FormatError(f"not a JPEG: starts with {data[:4].hex() or 'nothing'}")
    pos, exif, frame = 2, None, None
    n = len(data)
    while True:
        if pos >= n:
            raise Jp4FormatError(f"truncated JPEG: ends at byte {n} before the scan data")
        if data[pos] != 0xFF:
            raise Jp4FormatError(f"not a JPEG: byte {pos} is {data[pos]:#04x}, not a marker")
        while pos + 1 < n and data[pos + 1] == 0xFF:
            pos += 1  # fill bytes before a marker
        if pos + 2 > n:
            raise Jp4FormatError(f"truncated JPEG: ends at byte {n} before the scan data")
        marker = data[pos + 1]
        pos += 2
        if marker in _STANDALONE:
            continue
        if pos + 2 > n:
            raise Jp4FormatError(f"truncated JPEG: ends inside marker FF{marker:02X}")
        (length,) = struct.unpack_from(">H", data, pos)
        end = pos + length
        if length < 2 or end > n:
            raise Jp4FormatError(
                f"truncated JPEG: segment FF{marker:02X} at byte {pos - 2} needs "
                f"{length} bytes, the file ends at {n}"
            )
        body = data[pos + 2 : end]
        if marker == 0xE1 and body.startswith(_EXIF_HEADER) and exif is None:
            exif = bytes(body[len(_EXIF_HEADER) :])
        elif marker in _SOF:
            if len(body) < 6:
                raise Jp4FormatError(f"not a JPEG: frame header of {len(body)} bytes")
            height, width = struct.unpack_from(">HH", body, 1)
            frame = (width, height, body[5])
        elif marker == 0xDA:
            if frame is None:
                raise Jp4FormatError("not a JPEG: scan data before any frame header")
            if data.rfind(b"\xff\xd9", end) < 0:  # from the end: found at once
                raise Jp4FormatError(
                    f"truncated JPEG: no end-of-image marker after the scan data ({n} bytes)"
                )
            return JpegInfo(width=frame[0], height=frame[1], components=frame[2], exif=exif)
        elif marker == 0xD9:
            raise Jp4FormatError("not a JPEG: end-of-image marker before any scan data")
        pos = end


def _value(block: bytes, order: str, kind: int, count: int, raw: bytes) -> Any:
    if kind == 2:
        return raw.split(b"\0", 1)[0].decode("latin-1")
    if kind in (1, 6, 7):
        return bytes(raw)
    code = {3: "H", 4: "I", 8: "h", 9: "i", 5: "II", 10: "ii"}.get(kind)
    if code is None:
        return bytes(raw)
    values = struct.unpack(f"{order}{code * count}", raw)
    if kind in (5, 10):
        return tuple(zip(values[0::2], values[1::2], strict=True))
    return values


def _ifd(block: bytes, order: str, offset: int, what: str) -> tuple[dict[int, Any], int]:
    n = len(block)
    if offset < 8 or offset + 2 > n:
        raise Jp4FormatError(f"Exif: {what} at offset {offset} lies outside the {n}-byte block")
    (count,) = struct.unpack_from(f"{order}H", block, offset)
    table_end = offset + 2 + 12 * count
    if table_end + 4 > n:
        raise Jp4FormatError(f"Exif: {what} of {count} entries runs past the {n}-byte block")
    tags: dict[int, Any] = {}
    for i in range(count):
        tag, kind, num = struct.unpack_from(f"{order}HHI", block, offset + 2 + 12 * i)
        size = _TYPE_SIZE.get(kind, 1) * num
        if size <= 4:
            start = offset + 2 + 12 * i + 8
        else:
            (start,) = struct.unpack_from(f"{order}I", block, offset + 2 + 12 * i + 8)
            if start + size > n:
                raise Jp4FormatError(
                    f"Exif: tag {tag:#06x} ({num} values) at offset {start} runs past the "
                    f"{n}-byte block"
                )
        tags[tag] = (kind, _value(block, order, kind, num, block[start : start + size]))
    (next_ifd,) = struct.unpack_from(f"{order}I", block, table_end)
    return tags, next_ifd


@dataclass(frozen=True)
class ExifFields:
    """The Exif fields of an NC393 frame; None where the file does not have one.

    ``exposure_time`` is (numerator, denominator) seconds; ``maker_note`` the MakerNote's
    32-bit words (Elphel writes 16; older firmware 14, 12 or 8).
    """

    make: str | None = None
    model: str | None = None
    description: str | None = None
    image_number: int | None = None
    page_number: int | None = None
    exposure_time: tuple[int, int] | None = None
    date_time_original: str | None = None
    subsec_time_original: str | None = None
    maker_note: tuple[int, ...] | None = None


def _first_int(tags: dict[int, Any], tag: int) -> int | None:
    entry = tags.get(tag)
    if entry is None or entry[0] not in (3, 4, 8, 9) or not entry[1]:
        return None
    return int(entry[1][0])


def _text(tags: dict[int, Any], tag: int) -> str | None:
    entry = tags.get(tag)
    return entry[1] if entry is not None and entry[0] == 2 else None


def _maker_note(entry: tuple[int, Any] | None, order: str) -> tuple[int, ...] | None:
    if entry is None:
        return None
    kind, value = entry
    if kind == 4:
        return tuple(int(v) for v in value)
    if kind == 7 and len(value) % 4 == 0:  # the same words, stored as bytes
        return struct.unpack(f"{order}{len(value) // 4}I", value)
    raise Jp4FormatError(
        f"Exif: MakerNote of type {kind}; allowed: LONG words (type 4) as Elphel writes them"
    )


def read_exif(block: bytes) -> ExifFields:
    """Parse a TIFF structure (an Exif block, or a whole TIFF file) into `ExifFields`.

    Raises
    ------
    Jp4FormatError
        No TIFF header, or an IFD or value outside the block.
    """
    head = block[:4]
    if head == b"MM\0\x2a":
        order = ">"
    elif head == b"II\x2a\0":
        order = "<"
    else:
        raise Jp4FormatError(f"Exif: no TIFF header (starts with {head.hex() or 'nothing'})")
    if len(block) < 8:
        raise Jp4FormatError(f"Exif: block of {len(block)} bytes, too short for a TIFF header")
    (first,) = struct.unpack_from(f"{order}I", block, 4)
    ifd0, _ = _ifd(block, order, first, "IFD0")
    exif: dict[int, Any] = {}
    pointer = _first_int(ifd0, TAG_EXIF_IFD)
    if pointer is not None:
        exif, _ = _ifd(block, order, pointer, "Exif IFD")
    exposure = exif.get(TAG_EXPOSURE_TIME)
    return ExifFields(
        make=_text(ifd0, TAG_MAKE),
        model=_text(ifd0, TAG_MODEL),
        description=_text(ifd0, TAG_IMAGE_DESCRIPTION),
        image_number=_first_int(ifd0, TAG_IMAGE_NUMBER),
        page_number=_first_int(ifd0, TAG_PAGE_NUMBER),
        exposure_time=exposure[1][0] if exposure is not None and exposure[0] == 5 else None,
        date_time_original=_text(exif, TAG_DATE_TIME_ORIGINAL),
        subsec_time_original=_text(exif, TAG_SUBSEC_TIME_ORIGINAL),
        maker_note=_maker_note(exif.get(TAG_MAKER_NOTE), order),
    )
