"""Crafted files: TIFFs whose header claims what their data do not hold, and nested JSON."""

from __future__ import annotations

import io
import json
import struct
import zlib

import numpy as np
import tifffile

SHORT, LONG, ASCII = 3, 4, 2


def claiming_tiff(width: int, height: int, description: str = '{"frame": 1}') -> bytes:
    """A deflate TIFF whose header claims ``width`` x ``height`` 16-bit pixels; 1 KiB of data."""
    data = zlib.compress(bytes(1 << 20))[:1024]
    desc = description.encode() + b"\0"
    tags = [
        (256, LONG, 1, width),
        (257, LONG, 1, height),
        (258, SHORT, 1, 16),
        (259, SHORT, 1, 8),
        (262, SHORT, 1, 1),
        (270, ASCII, len(desc), 0),
        (273, LONG, 1, 0),
        (277, SHORT, 1, 1),
        (278, LONG, 1, height),
        (279, LONG, 1, len(data)),
    ]
    ifd_size = 2 + 12 * len(tags) + 4
    desc_at = 8 + ifd_size
    data_at = desc_at + len(desc)
    out = bytearray(b"II*\0" + struct.pack("<I", 8) + struct.pack("<H", len(tags)))
    for tag, kind, count, value in tags:
        value = {270: desc_at, 273: data_at}.get(tag, value)
        packed = struct.pack("<H", value) + b"\0\0" if kind == SHORT else struct.pack("<I", value)
        out += struct.pack("<HHI", tag, kind, count) + packed
    out += struct.pack("<I", 0) + desc + data
    return bytes(out)


def frame_tiff(metadata_json: str, shape: tuple[int, int] = (16, 16)) -> bytes:
    """A small 16-bit TIFF as the daemon sends one, with ``metadata_json`` as its description."""
    buffer = io.BytesIO()
    image = np.arange(shape[0] * shape[1], dtype=np.uint16).reshape(shape)
    tifffile.imwrite(buffer, image, description=metadata_json, metadata=None)
    return buffer.getvalue()


def nested_json(depth: int) -> str:
    """A JSON document nested ``depth`` lists deep."""
    return "[" * depth + "]" * depth


def frame_metadata(**changes: object) -> str:
    meta: dict[str, object] = {"frame": 7, "port": 0, "timestamp_ns": 1, "bayer": None}
    meta.update(changes)
    return json.dumps(meta)
