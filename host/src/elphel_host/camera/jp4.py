"""Elphel NC393 frames (JP4, JP46, mono JPEG, raw TIFF) decoded to linear 16-bit Bayer data.

`decode_jp4` takes a JPEG file as imgsrv serves it or the camera's recorder stores it
and returns the mosaic as the sensor read it out, linear, as a fraction of full scale
times 65535, black level subtracted, with the metadata an elphel-camd capture carries
(frame, timestamp_ns, port, bayer after the flips, EXPOS, gains, WOI, flips, COLOR) plus
``source``, ``gamma``, ``black_level``, ``gamma_scale`` and ``quality``. The JPEG itself
is decoded by Pillow (libjpeg-turbo); undoing the JP4/JP46 block layout is a reshape and
a transpose, undoing the gamma one lookup per pair of adjacent samples in a table built
from the two sites' inverse gamma tables (`elphel_host.camera.makernote`). `decode_frame`
also takes imgsrv's raw ``image/tiff`` (COLOR=15), so callers have one entry point.
"""

from __future__ import annotations

import calendar
import functools
import io
import re
import time
from typing import Any

import numpy as np
import tifffile
from numpy.typing import NDArray
from PIL import Image

from elphel_host import strict_json
from elphel_host.camera.exif import ExifFields, read_exif, scan_jpeg
from elphel_host.camera.makernote import FULL_SCALE, JP4, JP46, MONO, MakerNote, linear_lut
from elphel_host.errors import DeviceLimitError, Jp4FormatError
from elphel_host.limits import HostLimits, check_frame_shape

SOURCES = {JP4: "jp4", JP46: "jp46", MONO: "jpeg"}
RAW = 15
CONTENT_TYPES = ("image/jp4", "image/jp46", "image/jpeg", "image/tiff")
_MODE_OF_TYPE = {"image/jp4": JP4, "image/jp46": JP46}


def row_planes(pixels: NDArray[np.uint8], mode: int) -> NDArray[np.uint8]:
    """The readout mosaic of a decoded frame, as its even and its odd rows: (2, H/2, W).

    JP4 (5) and JP46 (2) blocks are put back in Bayer order; other modes are the pixels
    as they are. Splitting the rows by parity keeps each half contiguous, so the gamma
    lookup of the next step runs over plain arrays.
    """
    h, w = pixels.shape
    if mode == JP4:
        # jpeg [yb, half, y, xq, dy, dx, x] -> planes [dy, yb, y, half, xq, x, dx]
        j = pixels.reshape(h // 16, 2, 8, w // 32, 2, 2, 8)
        m = np.empty((2, h // 16, 8, 2, w // 32, 8, 2), dtype=np.uint8)
        for dx in (0, 1):  # one interleaved column at a time: long inner loops
            m[..., dx] = j[:, :, :, :, :, dx, :].transpose(4, 0, 2, 1, 3, 5)
    elif mode == JP46:
        # jpeg [yb, qy, y, xb, qx, x] -> planes [qy, yb, y, xb, x, qx]
        j = pixels.reshape(h // 16, 2, 8, w // 16, 2, 8)
        m = np.empty((2, h // 16, 8, w // 16, 8, 2), dtype=np.uint8)
        for dx in (0, 1):
            m[..., dx] = j[:, :, :, :, dx, :].transpose(1, 0, 2, 3, 4)
    else:
        m = np.ascontiguousarray(pixels.reshape(h // 2, 2, w).transpose(1, 0, 2))
    return m.reshape(2, h // 2, w)


@functools.lru_cache(maxsize=32)
def _pair_lut(
    left: tuple[float, float, int], right: tuple[float, float, int]
) -> NDArray[np.uint32]:
    """Two horizontally adjacent codes (one uint16 in memory) -> their two linear values."""
    both = np.arange(65536, dtype=np.uint16).view(np.uint8).reshape(65536, 2)
    values = np.empty((65536, 2), dtype=np.uint16)
    values[:, 0] = linear_lut(*left)[both[:, 0]]
    values[:, 1] = linear_lut(*right)[both[:, 1]]
    lut = values.view(np.uint32).reshape(65536)
    lut.setflags(write=False)
    return lut


def linearise(
    pixels: NDArray[np.uint8], note: MakerNote, *, mode: int | None = None
) -> NDArray[np.uint16]:
    """Undo the block layout and each site's gamma of an 8-bit frame.

    Parameters
    ----------
    pixels
        The decoded JPEG (H, W) uint8 (even sizes), or an 8-bit raw frame (mode 0).
    note
        The frame's MakerNote: gamma per channel, flips, BAYER_MODE.
    mode
        COLOR_MODE of the layout (default: the note's).

    Returns
    -------
    numpy.ndarray
        (H, W) uint16, linear: fraction of full scale times 65535, black subtracted.
    """
    mode = note.color_mode if mode is None else mode
    h, w = pixels.shape
    if h % 2 or w % 2:
        raise Jp4FormatError(f"frame {w}x{h}; allowed: even width and height (2x2 cells)")
    planes = row_planes(pixels, mode)
    out = np.empty((h, w), dtype=np.uint16)
    out_pairs = out.view(np.uint32)  # two horizontally adjacent samples each
    channels = note.site_channels()
    for dy in (0, 1):
        left, right = (
            (note.gamma[c], note.black[c], note.gamma_scale[c])
            for c in (int(channels[dy, 0]), int(channels[dy, 1]))
        )
        out_pairs[dy::2] = _pair_lut(left, right)[planes[dy].view(np.uint16)]
    return out


def _timestamp_ns(fields: ExifFields) -> int | None:
    text = fields.date_time_original
    if text is None:
        return None
    try:
        when = time.strptime(text.strip(), "%Y:%m:%d %H:%M:%S")
    except ValueError as e:
        raise Jp4FormatError(
            f"Exif DateTimeOriginal={text!r}; allowed: 'YYYY:MM:DD HH:MM:SS'"
        ) from e
    sub = (fields.subsec_time_original or "").strip()
    if sub and not re.fullmatch(r"\d{1,9}", sub):
        raise Jp4FormatError(f"Exif SubSecTimeOriginal={sub!r}; allowed: decimal digits")
    return calendar.timegm(when) * 1_000_000_000 + int(sub.ljust(9, "0") or 0)


def frame_metadata(fields: ExifFields, note: MakerNote | None, *, source: str) -> dict[str, Any]:
    """The capture metadata of a frame from its Exif fields and MakerNote.

    Keys as an elphel-camd capture has them (``frame``, ``timestamp_ns``, ``port``,
    ``bayer``, ``EXPOS``, gains, ``WOI_*``, ``FLIPH``, ``FLIPV``, ``COLOR``), each only when
    the file holds it, plus ``source`` and, from the MakerNote, ``BAYER``, ``gamma``,
    ``black_level`` (fractions of full scale), ``gamma_scale`` (per channel R, Gr, Gb, B),
    ``quality`` and ``full_scale_dn``. ``sensor`` is not in the file: callers add it.
    """
    meta: dict[str, Any] = {}
    if fields.image_number is not None:
        meta["frame"] = fields.image_number
    stamp = _timestamp_ns(fields)
    if stamp is not None:
        meta["timestamp_ns"] = stamp
    if fields.page_number is not None:
        meta["port"] = fields.page_number
    if note is not None:
        meta["bayer"] = None if note.color_mode == MONO else note.bayer
    if fields.exposure_time is not None and fields.exposure_time[1]:
        num, den = fields.exposure_time
        meta["EXPOS"] = round(num * 1_000_000 / den)
    if note is not None:
        meta.update(zip(("GAINR", "GAING", "GAINGB", "GAINB"), note.gains, strict=True))
        meta.update(zip(("WOI_LEFT", "WOI_TOP", "WOI_WIDTH", "WOI_HEIGHT"), note.woi, strict=True))
        meta.update({"FLIPH": note.fliph, "FLIPV": note.flipv, "BAYER": note.bayer_mode})
        meta.update({"DCM_HOR": note.decimation[0], "DCM_VERT": note.decimation[1]})
        meta.update({"BIN_HOR": note.binning[0], "BIN_VERT": note.binning[1]})
        meta["COLOR"] = note.color_mode
    meta["source"] = source
    if note is not None:
        meta["gamma"] = list(note.gamma)
        meta["black_level"] = list(note.black)
        meta["gamma_scale"] = list(note.gamma_scale)
        meta["quality"] = note.quality
        meta["full_scale_dn"] = FULL_SCALE
        if note.composite:
            meta["composite"] = True
    return meta


def _check_size(width: int, height: int, mode: int) -> None:
    need = {JP4: (32, 16), JP46: (16, 16)}.get(mode)
    if need is None:
        return
    name = SOURCES[mode].upper()
    if width % need[0]:
        raise Jp4FormatError(f"{name} frame {width}x{height}: width not a multiple of {need[0]}")
    if height % need[1]:
        raise Jp4FormatError(f"{name} frame {width}x{height}: height not a multiple of {need[1]}")


def _check_window(width: int, height: int, note: MakerNote, limits: HostLimits) -> None:
    """Refuse a JPEG whose SOF claims more than its MakerNote's window (or the limit) allows.

    Decimation and binning only shrink the window; a composite frame stacks sub-frames, so
    its height is not bounded by the window's.
    """
    check_frame_shape((height, width), limits, what="the JPEG's SOF")
    _, _, woi_width, woi_height = note.woi
    if (
        woi_width
        and woi_height
        and (width > woi_width or (height > woi_height and not note.composite))
    ):
        raise Jp4FormatError(
            f"the JPEG's SOF claims {width}x{height} but the MakerNote's window is "
            f"{woi_width}x{woi_height}; allowed: at most the window"
        )


def decode_jp4(
    data: bytes, *, limits: HostLimits | None = None
) -> tuple[NDArray[np.uint16], dict[str, Any]]:
    """Decode an NC393 JPEG frame (JP4, JP46 or mono) to linear 16-bit and its metadata.

    Parameters
    ----------
    data
        The file as imgsrv serves it or the recorder stores it.

    Returns
    -------
    image : numpy.ndarray
        (H, W) uint16, the mosaic as read out (its order is ``metadata["bayer"]``):
        linear value as a fraction of full scale times 65535, the black level
        subtracted, the gains not divided out.
    metadata : dict
        See `frame_metadata`.

    Raises
    ------
    Jp4FormatError
        Not a JPEG, truncated, no Exif or MakerNote, a short MakerNote, an unknown
        COLOR_MODE, a colour JPEG, a size the mode does not allow, or a size larger than
        the MakerNote's window.
    DeviceLimitError
        A size beyond ``limits.frame_pixels`` (default `HostLimits.from_env`).
    """
    info = scan_jpeg(data)
    if info.exif is None:
        raise Jp4FormatError("no Exif (APP1) block: not a frame from an Elphel camera")
    fields = read_exif(info.exif)
    if fields.maker_note is None:
        raise Jp4FormatError("no MakerNote (Exif tag 0x927C): not a frame from an Elphel camera")
    note = MakerNote.from_words(fields.maker_note)
    mode = note.color_mode
    if mode not in SOURCES:
        raise Jp4FormatError(
            f"unknown COLOR_MODE {mode} in the MakerNote; allowed: 5 (JP4), 2 (JP46), 0 (mono)"
        )
    if info.components != 1:
        raise Jp4FormatError(
            f"{info.components}-component JPEG with COLOR_MODE {mode}: a colour JPEG is "
            "demosaiced by the camera, not raw data (record with COLOR=5, JP4)"
        )
    _check_size(info.width, info.height, mode)
    _check_window(info.width, info.height, note, limits or HostLimits.from_env())
    try:
        with Image.open(io.BytesIO(data)) as im:
            im.load()
            pixels = np.asarray(im)
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError) as e:
        raise Jp4FormatError(f"JPEG data cannot be decoded: {e}") from e
    if pixels.dtype != np.uint8 or pixels.shape != (info.height, info.width):
        raise Jp4FormatError(
            f"JPEG decoded to {pixels.dtype} {pixels.shape}; expected uint8 "
            f"({info.height}, {info.width})"
        )
    return linearise(pixels, note), frame_metadata(fields, note, source=SOURCES[mode])


def decode_tiff(
    data: bytes, *, limits: HostLimits | None = None
) -> tuple[NDArray[np.uint16], dict[str, Any]]:
    """Decode imgsrv's raw frame (COLOR=15): a 16-bit TIFF, or an 8-bit one with a MakerNote.

    A 16-bit frame is returned as it is (the camera bypasses the gamma); an 8-bit frame
    went through the gamma tables and is linearised like a mono JPEG. Metadata: the
    ImageDescription's JSON object if it holds one, and the Exif fields if there are any.
    The size the TIFF claims is checked against ``limits`` before it is decoded.
    """
    limits = limits or HostLimits.from_env()
    try:
        with tifffile.TiffFile(io.BytesIO(data)) as tif:
            check_frame_shape(tuple(tif.pages.first.shape), limits, what="the raw TIFF")
            image = tif.asarray()
            description = tif.pages.first.description
    except DeviceLimitError:
        raise
    except Exception as e:  # tifffile raises many kinds on a damaged file
        raise Jp4FormatError(f"not a readable TIFF: {e}") from e
    if image.ndim != 2:
        raise Jp4FormatError(f"TIFF of shape {image.shape}; allowed: one 2-D raw frame")
    fields = read_exif(data)
    note = MakerNote.from_words(fields.maker_note) if fields.maker_note else None
    meta = frame_metadata(fields, note, source="tiff")
    meta["COLOR"] = RAW
    try:
        described = (
            strict_json.loads(description, what="", limit_bytes=limits.json_bytes)
            if description
            else None
        )
    except ValueError:
        described = None
    if isinstance(described, dict):
        described.pop("shape", None)
        meta = {**described, **meta}
    if image.dtype == np.uint8:
        if note is None:
            raise Jp4FormatError("8-bit raw TIFF without a MakerNote: its gamma is unknown")
        return linearise(image, note, mode=MONO), meta
    if image.dtype != np.uint16:
        raise Jp4FormatError(f"TIFF of {image.dtype}; allowed: uint16 (BITS=16) or uint8")
    for key in ("gamma", "black_level", "gamma_scale", "full_scale_dn"):
        meta.pop(key, None)  # 16-bit raw data bypass the gamma tables
    return np.asarray(image, dtype=np.uint16), meta


def decode_frame(data: bytes, content_type: str) -> tuple[NDArray[np.uint16], dict[str, Any]]:
    """Decode any frame imgsrv serves, by its Content-Type (parameters ignored).

    ``image/jp4``, ``image/jp46`` and ``image/jpeg`` go to `decode_jp4` (the MakerNote's
    COLOR_MODE must agree with a jp4/jp46 type), ``image/tiff`` to `decode_tiff`.
    """
    kind = content_type.split(";", 1)[0].strip().lower()
    if kind == "image/tiff":
        return decode_tiff(data)
    if kind not in CONTENT_TYPES:
        raise Jp4FormatError(f"content type {content_type!r}; allowed: {', '.join(CONTENT_TYPES)}")
    image, meta = decode_jp4(data)
    expected = _MODE_OF_TYPE.get(kind)
    if expected is not None and meta["COLOR"] != expected:
        raise Jp4FormatError(
            f"content type {kind} but the MakerNote says COLOR_MODE {meta['COLOR']}"
        )
    return image, meta
