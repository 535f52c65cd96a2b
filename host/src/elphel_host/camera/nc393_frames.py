"""Frames from a stock NC393 as elphel-camd captures: 16-bit TIFF bytes with JSON metadata.

imgsrv's answer (JP4, JP46, JPEG, or raw TIFF with COLOR 15) is decoded by
`elphel_host.camera.jp4.decode_frame`; the metadata get the keys an elphel-camd capture
has (``frame``, ``timestamp_ns``, ``port``, ``sensor``, ``bayer``, then the parameters),
so burst and quad directories store identical files whichever camera took them.
"""

from __future__ import annotations

import io
import json
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import tifffile

from elphel_camd.frame_metadata import bayer_after_flips
from elphel_host.camera.frames import CapturedBurst, CapturedFrame
from elphel_host.camera.jp4 import decode_frame
from elphel_host.errors import CameraClientError, InputFormatError

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


def tiff_bytes(image: np.ndarray, metadata: Mapping[str, Any]) -> bytes:
    """One 16-bit TIFF page with the metadata as JSON in its ImageDescription."""
    buffer = io.BytesIO()
    tifffile.imwrite(buffer, image, description=json.dumps(dict(metadata)), metadata=None)
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
) -> CapturedFrame:
    """Decode one imgsrv answer into a `CapturedFrame` (errors name the URL)."""
    try:
        image, decoded = decode_frame(data, content_type)
    except InputFormatError as e:
        raise CameraClientError(f"{url}: {e}") from e
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
            tif.write(f.image, description=json.dumps(f.metadata), metadata=None)
    images = np.stack([f.image for f in frames])
    return CapturedBurst(
        tiff=buffer.getvalue(), images=images, metadata=[f.metadata for f in frames]
    )
