"""Frames from a stock NC393 as elphel-camd captures: 16-bit TIFF bytes with JSON metadata.

imgsrv's answer (JP4, JP46, JPEG, or raw TIFF with COLOR 15) is decoded by
`elphel_host.camera.jp4.decode_frame`; the metadata get the keys an elphel-camd capture
has (``frame``, ``timestamp_ns``, ``port``, ``sensor``, ``bayer``, then the parameters),
so burst and quad directories store identical files whichever camera took them.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import httpx
import numpy as np
import tifffile

from elphel_camd.frame_metadata import bayer_after_flips
from elphel_host import strict_json
from elphel_host.camera.exif import read_exif
from elphel_host.camera.frames import CapturedBurst, CapturedFrame
from elphel_host.camera.jp4 import decode_frame
from elphel_host.camera.jp4 import frame_metadata as exif_metadata
from elphel_host.camera.nc393 import imgsrv
from elphel_host.errors import (
    CameraClientError,
    DeviceLimitError,
    DeviceTimeout,
    InputFormatError,
)
from elphel_host.limits import Deadline, HostLimits, read_bounded

_FIRST = ("frame", "timestamp_ns", "port", "sensor", "bayer")


def frame_metadata(
    decoded: Mapping[str, Any],
    *,
    port: int,
    sensor: str,
    bayer: str | None,
    params: Mapping[str, int],
) -> dict[str, Any]:
    """A capture's metadata: what the frame records, over the parameters read meanwhile.

    The frame's own values (Exif, MakerNote) win over ``params``, which were read when the
    frame was fetched; ``FRAME`` is the frame's number. ``bayer`` is the sensor's order
    unflipped, used (after the flips) when the frame does not say its own (a raw TIFF).
    """
    for key in ("frame", "timestamp_ns"):
        if key not in decoded:
            raise CameraClientError(f"port {port}: the frame carries no {key}")
    out: dict[str, Any] = {
        "frame": int(decoded["frame"]),
        "timestamp_ns": int(decoded["timestamp_ns"]),
        "port": port,
        "sensor": sensor,
        "bayer": decoded.get("bayer"),
    }
    if "bayer" not in decoded:
        flips = {k: int(decoded.get(k, params.get(k, 0))) for k in ("FLIPH", "FLIPV")}
        out["bayer"] = bayer_after_flips(bayer, flips["FLIPH"], flips["FLIPV"])
    out.update({k: v for k, v in params.items() if k not in _FIRST})
    out.update({k: v for k, v in decoded.items() if k not in _FIRST})
    out["FRAME"] = out["frame"]
    return out


def exif_block(head: bytes) -> bytes | None:
    """The Exif block of a JPEG from its first bytes; None while more bytes are needed.

    Walks the marker segments from the start of the file up to the APP1 Exif segment
    (imgsrv writes it first), so a frame's number and time are known from a few KiB.

    Raises
    ------
    InputFormatError
        Not a JPEG, or the scan data start before any Exif block.
    """
    if len(head) >= 2 and head[:2] != b"\xff\xd8":
        raise InputFormatError(f"not a JPEG: starts with {head[:4].hex()}")
    pos = 2
    while pos + 4 <= len(head):
        if head[pos] != 0xFF:
            raise InputFormatError(f"not a JPEG: byte {pos} is {head[pos]:#04x}, not a marker")
        marker = head[pos + 1]
        end = pos + 2 + int.from_bytes(head[pos + 2 : pos + 4], "big")
        if marker == 0xDA:
            raise InputFormatError("no Exif block before the scan data")
        if end > len(head):
            return None
        if marker == 0xE1 and head[pos + 4 : pos + 10] == b"Exif\0\0":
            return head[pos + 10 : end]
        pos = end
    return None


def header_stamp(block: bytes, *, url: str) -> tuple[int, int]:
    """``(frame, timestamp_ns)`` from a frame's Exif block (errors name the URL)."""
    try:
        meta = exif_metadata(read_exif(block), None, source="exif")
    except InputFormatError as e:
        raise CameraClientError(f"{url}: {e}") from e
    if "frame" not in meta or "timestamp_ns" not in meta:
        raise CameraClientError(f"{url}: the frame's Exif has no ImageNumber or DateTimeOriginal")
    return int(meta["frame"]), int(meta["timestamp_ns"])


def newest_stamp(
    client: httpx.Client, raw: Callable[[bytes, str, str], CapturedFrame], *, limits: HostLimits
) -> tuple[int, int]:
    """``(frame, timestamp_ns)`` of imgsrv's newest frame, from its first KiB.

    The answer is streamed only up to the Exif block of a JPEG frame, at most
    ``limits.jpeg_head_bytes`` of segments before it; a raw TIFF frame (its tags may be
    anywhere) is read whole, within the frame limit, and decoded by ``raw(data, type, url)``.
    """
    url = str(client.base_url).rstrip("/") + imgsrv.NEWEST
    deadline = Deadline(limits.deadline_s, what=f"GET {imgsrv.NEWEST}")
    try:
        with client.stream("GET", imgsrv.NEWEST) as response:
            if response.status_code >= 400:
                raise CameraClientError(f"{url}: HTTP {response.status_code}")
            kind = imgsrv.image_type(response.headers.get("content-type"), url=url)
            if kind == "image/tiff":
                data = read_bounded(
                    response.iter_bytes(),
                    limit_bytes=limits.frame_bytes + limits.json_bytes,
                    deadline=deadline,
                    what=f"the camera at {url}",
                    limit_name="frame_pixels",
                )
                got = raw(data, kind, url)
                return got.frame, int(got.metadata["timestamp_ns"])
            head = b""
            for chunk in response.iter_bytes():
                head += chunk
                deadline.check()
                if len(head) > limits.jpeg_head_bytes:
                    raise DeviceLimitError(
                        f"the camera at {url}: no Exif block in the first "
                        f"{limits.jpeg_head_bytes} bytes "
                        "(limit jpeg_head_bytes; raise ELPHEL_LIMIT_JPEG_HEAD_BYTES)"
                    )
                try:
                    block = exif_block(head)
                except InputFormatError as e:
                    raise CameraClientError(f"{url}: {e}") from e
                if block is not None:
                    return header_stamp(block, url=url)
    except httpx.TimeoutException as e:
        raise DeviceTimeout(f"the camera at {url} did not answer in time: {e}") from e
    except httpx.HTTPError as e:
        raise CameraClientError(f"cannot reach the camera at {url}: {e}") from e
    raise CameraClientError(f"{url}: the frame ended before its Exif block")


def tiff_bytes(image: np.ndarray, metadata: Mapping[str, Any]) -> bytes:
    """One 16-bit TIFF page with the metadata as JSON in its ImageDescription."""
    buffer = io.BytesIO()
    description = strict_json.dumps(dict(metadata), what="the frame's metadata")
    tifffile.imwrite(buffer, image, description=description, metadata=None)
    return buffer.getvalue()


def decoded_frame(
    data: bytes,
    content_type: str,
    *,
    url: str,
    port: int,
    sensor: str,
    bayer: str | None,
    params: Mapping[str, int],
    bits: int,
) -> CapturedFrame:
    """Decode one imgsrv answer into a `CapturedFrame` (errors name the URL).

    Compressed frames (JP4, JP46, JPEG) decode to fractions of full scale; they are put on
    the sensor's own scale (0 .. 2**bits - 1 DN, ``bits`` of the sensor model), the scale
    of a raw (COLOR 15) frame and of an elphel-camd capture, so a burst or quad set is in
    the same units whichever camera and whichever COLOR took it.
    """
    try:
        image, decoded = decode_frame(data, content_type)
    except InputFormatError as e:
        raise CameraClientError(f"{url}: {e}") from e
    full_scale = decoded.get("full_scale_dn")
    top = (1 << bits) - 1
    if full_scale is not None and int(full_scale) != top:
        scaled = np.asarray(image, dtype=np.float64) * (top / int(full_scale))
        image = np.rint(scaled).astype(np.uint16)
        decoded = {**decoded, "full_scale_dn": top}
    image = np.asarray(image, dtype=np.uint16)
    metadata = frame_metadata(decoded, port=port, sensor=sensor, bayer=bayer, params=params)
    return CapturedFrame(tiff=tiff_bytes(image, metadata), image=image, metadata=metadata)


def tiff_pages(frames: Sequence[CapturedFrame]) -> CapturedBurst:
    """Consecutive frames as one multi-page TIFF, as elphel-camd sends a burst."""
    shapes = {f.image.shape for f in frames}
    if len(shapes) != 1:
        raise CameraClientError(
            f"burst frames {frames[0].frame}..{frames[-1].frame} differ in size: "
            f"{sorted(shapes)}; allowed: one size"
        )
    buffer = io.BytesIO()
    with tifffile.TiffWriter(buffer) as tif:
        for f in frames:
            meta = strict_json.dumps(f.metadata, what=f"frame {f.frame}'s metadata")
            tif.write(f.image, description=meta, metadata=None)
    images = np.stack([f.image for f in frames])
    return CapturedBurst(
        tiff=buffer.getvalue(), images=images, metadata=[f.metadata for f in frames]
    )
