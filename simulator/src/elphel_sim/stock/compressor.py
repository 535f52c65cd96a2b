"""The stock NC393's compressor parameters of one port, by frame, and its file formats.

The daemon's parameter model (`elphel_camd`) has no compressor: its frames are raw
16-bit. A stock NC393 has one per port, set by COLOR, QUALITY and the four gamma words
GTAB_R, GTAB_G, GTAB_GB, GTAB_B (black level << 24 | gamma x 100 << 16 | scale,
0x400 = 1.0). `CompressorSchedule` keeps them frame by frame, as the sensor's
parameters are kept, and `encode_frame` turns a read-out frame into the file imgsrv
serves: JP4 or JP46 through `elphel_sim.jp4.encode_jp4`, or a 16-bit TIFF for COLOR 15.
"""

from __future__ import annotations

import struct
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elphel_sim.jp4 import JP4, JP46, encode_jp4, file_head, maker_note

RAW = 15
GAMMA_NAMES = ("GTAB_R", "GTAB_G", "GTAB_GB", "GTAB_B")  # MakerNote channels 0..3
ELPHEL_GAMMA = 0x0A390400  # Elphel's default: black 10/256, gamma 0.57, scale 1.0
BAYER_DEFAULTS = {"COLOR": JP4, "QUALITY": 100, **dict.fromkeys(GAMMA_NAMES, ELPHEL_GAMMA)}
# The Lepton's frames bypass the compressor: always raw 16-bit.
RAW_DEFAULTS = {"COLOR": RAW, "QUALITY": 100, **dict.fromkeys(GAMMA_NAMES, ELPHEL_GAMMA)}
NAMES = frozenset(BAYER_DEFAULTS)
EXIF_IFD = 0x8769  # the Exif IFD pointer tag
_ASCII, _SHORT, _LONG, _RATIONAL = 2, 3, 4, 5  # TIFF field types
KEEP_FRAMES = 256  # frames of history kept (the sensor parameters keep as many)


def valid(name: str, value: int, *, raw_only: bool) -> bool:
    """Whether the compressor takes this value (the stock camera ignores the others)."""
    if name == "COLOR":
        return value == RAW if raw_only else value in (JP4, JP46, RAW)
    if name == "QUALITY":
        return 1 <= value <= 100
    gamma, black, scale = (value >> 16) & 0xFF, value >> 24, value & 0xFFFF
    return 0 <= value <= 0xFFFFFFFF and gamma >= 13 and scale > 0 and black <= 0xFF


class CompressorSchedule:
    """One port's compressor parameters: in effect now and scheduled for later frames.

    Parameters
    ----------
    raw_only
        The port's sensor delivers raw frames only (the Lepton): COLOR stays 15.
    """

    def __init__(self, *, raw_only: bool) -> None:
        self.raw_only = raw_only
        self._base: dict[str, int] = dict(RAW_DEFAULTS if raw_only else BAYER_DEFAULTS)
        self._base_frame = 0
        self._changes: dict[int, dict[str, int]] = {}
        self._lock = threading.Lock()  # parsedit writes while imgsrv threads read

    def set(self, frame: int, changes: Mapping[str, int]) -> dict[str, int]:
        """Schedule changes for ``frame`` and later; return those accepted (valid ones)."""
        taken = {k: v for k, v in changes.items() if valid(k, v, raw_only=self.raw_only)}
        if taken:
            with self._lock:
                target = max(frame, self._base_frame + 1)
                self._changes[target] = {**self._changes.get(target, {}), **taken}
        return taken

    def state_at(self, frame: int) -> dict[str, int]:
        """The compressor parameters in effect for a frame."""
        with self._lock:
            old = [t for t in self._changes if t < frame - KEEP_FRAMES]
            for target in sorted(old):
                self._base.update(self._changes.pop(target))
                self._base_frame = target
            state = dict(self._base)
            for target in sorted(self._changes):
                if target > frame:
                    break
                state.update(self._changes[target])
        return state


@dataclass(frozen=True)
class EncodedFrame:
    """A file as imgsrv serves it: bytes, MIME type and the extension of its name."""

    data: bytes
    content_type: str
    extension: str


def gamma_fields(word: int) -> tuple[float, float, int]:
    """(gamma, black level as a fraction of full scale, scale) of a GTAB word."""
    return ((word >> 16) & 0xFF) / 100, (word >> 24) / 256, word & 0xFFFF


def _macroblocks(image: NDArray[np.uint16], color: int) -> NDArray[np.uint16]:
    """The part of a frame the compressor takes: whole macroblocks (top-left)."""
    h, w = image.shape
    unit = 32 if color == JP4 else 16
    return image[: h - h % 16, : w - w % unit]


def encode_frame(
    image: NDArray[np.uint16],
    metadata: Mapping[str, Any],
    compressor: Mapping[str, int],
    *,
    bits: int,
) -> EncodedFrame:
    """A read-out frame as the stock camera's imgsrv serves it.

    Parameters
    ----------
    image
        The frame as the sensor read it out, (H, W), ``bits`` significant bits.
    metadata
        The frame's metadata as the daemon gives it (`elphel_camd.frame_metadata`):
        frame, timestamp_ns, port, EXPOS, gains, WOI_*, FLIPH, FLIPV.
    compressor
        The compressor parameters in effect for the frame (`CompressorSchedule.state_at`).
    bits
        The sensor's sample depth.
    """
    color = compressor["COLOR"]
    gammas = [gamma_fields(compressor[k]) for k in GAMMA_NAMES]
    if color == RAW:
        note = _note(metadata, compressor, image.shape)
        return EncodedFrame(raw_tiff(image, metadata, note), "image/tiff", "tiff")
    part = _macroblocks(image, color)
    left, top = int(metadata.get("WOI_LEFT", 0)), int(metadata.get("WOI_TOP", 0))
    data = encode_jp4(
        part,
        bits=bits,
        frame=int(metadata["frame"]),
        timestamp_ns=int(metadata["timestamp_ns"]),
        port=int(metadata["port"]),
        exposure_us=int(metadata.get("EXPOS", 0)),
        color_mode=color,
        quality=compressor["QUALITY"],
        gamma=[g[0] for g in gammas],
        black=[g[1] for g in gammas],
        gamma_scale=[g[2] for g in gammas],
        gains=_gains(metadata),
        flips=_flips(metadata),
        woi=(left, top, part.shape[1], part.shape[0]),
    )
    extension = "jp4" if color == JP4 else "jp46"
    return EncodedFrame(data, f"image/{extension}", extension)


def frame_head(
    metadata: Mapping[str, Any], compressor: Mapping[str, int], *, shape: tuple[int, int]
) -> EncodedFrame | None:
    """The first bytes of `encode_frame`'s JP4 or JP46 file, from the metadata alone.

    The start marker and the APP1 Exif segment (frame number, port, time, exposure,
    MakerNote) do not depend on the pixels, so a client reading only them (a frame's
    number and time) needs no image formed. ``shape`` is the read-out frame's (H, W).
    None for a raw frame (COLOR 15): a TIFF's tags are not all before its pixels.
    """
    color = compressor["COLOR"]
    if color == RAW:
        return None
    h, w = shape
    unit = 32 if color == JP4 else 16
    note = _note(metadata, compressor, (h - h % 16, w - w % unit))
    data = file_head(
        frame=int(metadata["frame"]),
        port=int(metadata["port"]),
        timestamp_ns=int(metadata["timestamp_ns"]),
        exposure_us=int(metadata.get("EXPOS", 0)),
        note=note,
    )
    extension = "jp4" if color == JP4 else "jp46"
    return EncodedFrame(data, f"image/{extension}", extension)


def _gains(metadata: Mapping[str, Any]) -> list[int]:
    return [int(metadata.get(k, 0x10000)) for k in ("GAINR", "GAING", "GAINGB", "GAINB")]


def _flips(metadata: Mapping[str, Any]) -> tuple[int, int]:
    return int(metadata.get("FLIPH", 0)), int(metadata.get("FLIPV", 0))


def _note(
    metadata: Mapping[str, Any], compressor: Mapping[str, int], shape: tuple[int, ...]
) -> list[int]:
    """The MakerNote of a frame encoded at ``shape`` (H, W) with these settings."""
    gammas = [gamma_fields(compressor[k]) for k in GAMMA_NAMES]
    left, top = int(metadata.get("WOI_LEFT", 0)), int(metadata.get("WOI_TOP", 0))
    return maker_note(
        gains=_gains(metadata),
        gamma=[g[0] for g in gammas],
        black=[g[1] for g in gammas],
        gamma_scale=[g[2] for g in gammas],
        woi=(left, top, int(shape[1]), int(shape[0])),
        flips=_flips(metadata),
        bayer_mode=0,
        color_mode=compressor["COLOR"],
        quality=compressor["QUALITY"],
    )


def ifd_bytes(entries: list[tuple[int, int, int, bytes]], start: int) -> bytes:
    """One big-endian TIFF IFD written at file offset ``start`` (values after it).

    ``entries`` are (tag, type, count, value bytes); values over 4 bytes go after the
    IFD, word aligned.
    """
    entries = sorted(entries)
    data_at = start + 2 + 12 * len(entries) + 4
    head, data = [struct.pack(">H", len(entries))], b""
    for tag, kind, count, payload in entries:
        if len(payload) <= 4:
            head.append(struct.pack(">HHI", tag, kind, count) + payload.ljust(4, b"\0"))
        else:
            head.append(struct.pack(">HHII", tag, kind, count, data_at + len(data)))
            data += payload + b"\0" * (len(payload) % 2)
    return b"".join(head) + b"\0\0\0\0" + data


def raw_tiff(image: NDArray[np.uint16], metadata: Mapping[str, Any], note: list[int]) -> bytes:
    """A raw frame as a big-endian 16-bit TIFF carrying the Exif fields a JPEG frame has.

    IFD0 holds the image tags, Make, Model, Software, DateTime, ImageNumber (0x9211, the
    frame), PageNumber (0x0129, the port) and the Exif IFD pointer; the Exif IFD holds
    ExposureTime, DateTimeOriginal, SubSecTimeOriginal (microseconds) and the 16-word
    MakerNote (0x927C, LONG): the same structure as the Exif block of a JP4 frame. One
    strip, uncompressed, minisblack.
    """
    pixels = np.ascontiguousarray(image, dtype=">u2")
    height, width = pixels.shape
    ns = int(metadata["timestamp_ns"])
    stamp = datetime.fromtimestamp(ns // 1_000_000_000, tz=UTC).strftime("%Y:%m:%d %H:%M:%S")
    usec = f"{(ns // 1000) % 1_000_000:06d}".encode("ascii") + b"\0"
    stamp_z = stamp.encode("ascii") + b"\0"

    def text(value: str) -> tuple[int, bytes]:
        raw = value.encode("ascii") + b"\0"
        return len(raw), raw

    def ifd0(exif_at: int, strip_at: int) -> bytes:
        return ifd_bytes(
            [
                (256, _LONG, 1, struct.pack(">I", width)),
                (257, _LONG, 1, struct.pack(">I", height)),
                (258, _SHORT, 1, struct.pack(">H", 16)),
                (259, _SHORT, 1, struct.pack(">H", 1)),  # no compression
                (262, _SHORT, 1, struct.pack(">H", 1)),  # minisblack
                (0x010F, _ASCII, *text("Elphel")),
                (0x0110, _ASCII, *text("NC393")),
                (273, _LONG, 1, struct.pack(">I", strip_at)),
                (277, _SHORT, 1, struct.pack(">H", 1)),
                (278, _LONG, 1, struct.pack(">I", height)),
                (279, _LONG, 1, struct.pack(">I", pixels.nbytes)),
                (0x0129, _SHORT, 2, struct.pack(">HH", int(metadata["port"]), 4)),
                (0x0131, _ASCII, *text("elphel-sim")),
                (0x0132, _ASCII, len(stamp_z), stamp_z),
                (EXIF_IFD, _LONG, 1, struct.pack(">I", exif_at)),
                (0x9211, _LONG, 1, struct.pack(">I", int(metadata["frame"]) & 0xFFFFFFFF)),
            ],
            8,
        )

    exif_at = 8 + len(ifd0(0, 0))
    note_bytes = struct.pack(f">{len(note)}I", *(w & 0xFFFFFFFF for w in note))
    exposure = struct.pack(">II", int(metadata.get("EXPOS", 0)), 1_000_000)
    exif = ifd_bytes(
        [
            (0x829A, _RATIONAL, 1, exposure),
            (0x9003, _ASCII, len(stamp_z), stamp_z),
            (0x9291, _ASCII, len(usec), usec),
            (0x927C, _LONG, len(note), note_bytes),
        ],
        exif_at,
    )
    strip_at = exif_at + len(exif)
    return b"MM\0\x2a" + struct.pack(">I", 8) + ifd0(exif_at, strip_at) + exif + pixels.tobytes()
