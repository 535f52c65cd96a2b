"""Frames as the camera daemon sends them: TIFF bytes with JSON metadata, decoded.

A capture is one 16-bit TIFF whose ImageDescription is the frame's metadata (JSON, as
tifffile writes ``metadata=``); ``?count=N`` gives N consecutive frames as one multi-page
TIFF; photo-finish composites of consecutive frames join into one image with each row's
time.
"""

from __future__ import annotations

import io
import itertools
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np
import tifffile
from numpy.typing import NDArray

from elphel_host import strict_json
from elphel_host.errors import CameraClientError, DeviceAnswerError, DeviceLimitError
from elphel_host.limits import HostLimits, check_frame_shape


@dataclass(frozen=True)
class CapturedFrame:
    """A frame as the daemon sent it: the TIFF bytes, the image and its metadata."""

    tiff: bytes
    image: NDArray[np.uint16]
    metadata: dict[str, Any]

    @property
    def frame(self) -> int:
        return int(self.metadata["frame"])


@dataclass(frozen=True)
class CapturedBurst:
    """Consecutive frames in one multi-page TIFF: images and per-frame metadata.

    ``images`` is one (N, H, W) array when every page has the same shape, else a list of
    the N pages (the window changed during the capture). ``complete`` is False for the
    pages kept of a burst that broke off (``keep_partial``).
    """

    tiff: bytes
    images: NDArray[np.uint16] | list[NDArray[np.uint16]]
    metadata: list[dict[str, Any]]
    complete: bool = True

    @property
    def frames(self) -> list[int]:
        return [int(m["frame"]) for m in self.metadata]

    def photofinish(self) -> PhotoFinish:
        """Join consecutive photo-finish composites into one image, with each row's time.

        Raises `CameraClientError` if the frames are not photo-finish composites of one
        shape, or if a strip is missing between two of them.
        """
        if not self.metadata or any("pf_strip_period_ns" not in m for m in self.metadata):
            raise CameraClientError("not photo-finish composites: set PF_HEIGHT first")
        first = self.metadata[0]
        height, period = int(first["PF_HEIGHT"]), int(first["pf_strip_period_ns"])
        strips = int(first["pf_strips"])
        for a, b in itertools.pairwise(self.metadata):
            if (b["PF_HEIGHT"], b["pf_strips"], b["pf_strip_period_ns"]) != (
                height,
                strips,
                period,
            ):
                raise CameraClientError(
                    f"frames {a['frame']} and {b['frame']}: photo-finish settings changed"
                )
            gap = int(b["timestamp_ns"]) - int(a["timestamp_ns"]) - strips * period
            if abs(gap) > period // 2:
                raise CameraClientError(
                    f"frames {a['frame']} and {b['frame']} are not contiguous: "
                    f"{gap / period:+.1f} strips between them"
                )
        if isinstance(self.images, list):
            raise CameraClientError("the frames differ in shape: the window changed")
        starts = np.array([int(m["timestamp_ns"]) for m in self.metadata], dtype=np.int64)
        strip = np.arange(strips * height, dtype=np.int64) // height
        row_times = starts[:, None] + strip[None, :] * period
        image = self.images.reshape(-1, self.images.shape[-1])
        return PhotoFinish(image, row_times.reshape(-1), height, period, self.frames)


@dataclass(frozen=True)
class PhotoFinish:
    """Photo-finish composites joined: one row per scan-line time.

    ``row_times_ns[r]`` is when row ``r`` was read (the start of its strip, on the
    camera's clock); rows run forward in time.
    """

    image: NDArray[np.uint16]
    row_times_ns: NDArray[np.int64]
    strip_height: int
    strip_period_ns: int
    frames: list[int]


def _description(text: str | bytes | None, *, what: str, limits: HostLimits) -> dict[str, Any]:
    """A page's JSON metadata: strict JSON, one object (``{}`` when there is none)."""
    if not text:
        return {}
    try:
        metadata = strict_json.loads(text, what=what, limit_bytes=limits.json_bytes)
    except DeviceAnswerError as e:
        raise CameraClientError(f"TIFF ImageDescription is not JSON metadata: {e}") from e
    if not isinstance(metadata, dict):
        raise DeviceAnswerError(f"{what}: the TIFF's metadata is not a JSON object")
    metadata.pop("shape", None)
    return metadata


def _checked_pages(tif: tifffile.TiffFile, *, what: str, limits: HostLimits) -> list[Any]:
    """The pages of ``tif``, each one's claimed size checked before anything is decoded."""
    pages: list[Any] = []
    for page in tif.pages:
        if len(pages) >= limits.burst_frames:
            raise DeviceLimitError(
                f"{what}: more than {limits.burst_frames} pages "
                "(limit burst_frames; raise ELPHEL_LIMIT_BURST_FRAMES)"
            )
        check_frame_shape(tuple(page.shape), limits, what=what)
        pages.append(page)
    return pages


def read_tiff_metadata(
    data: bytes | str, *, limits: HostLimits | None = None, what: str = "a TIFF"
) -> tuple[NDArray[Any], dict[str, Any]]:
    """Image and JSON metadata (ImageDescription) of a TIFF written by the daemon.

    The image's claimed size is checked against ``limits`` (default `HostLimits`) before
    it is decoded; a larger one raises `DeviceLimitError`.
    """
    limits = limits or HostLimits()
    source: Any = io.BytesIO(data) if isinstance(data, bytes) else data
    with tifffile.TiffFile(source) as tif:
        first = _checked_pages(tif, what=what, limits=limits)[0]
        image = first.asarray()
        description = first.description
    return image, _description(description, what=what, limits=limits)


def read_tiff_pages(
    data: bytes, *, limits: HostLimits | None = None, what: str = "a TIFF"
) -> tuple[NDArray[Any] | list[NDArray[Any]], list[dict[str, Any]]]:
    """Images and each page's JSON metadata of a multi-page TIFF from the daemon.

    The images are one (N, H, W) array if all pages have one shape, else a list of pages.
    Page count and sizes are checked against ``limits`` before decoding.
    """
    limits = limits or HostLimits()
    with tifffile.TiffFile(io.BytesIO(data)) as tif:
        pages = _checked_pages(tif, what=what, limits=limits)
        metadata = [_description(p.description, what=what, limits=limits) for p in pages]
        arrays = [page.asarray() for page in pages]
    if len({a.shape for a in arrays}) > 1:
        return arrays, metadata
    return np.stack(arrays), metadata


def read_partial_tiff(
    data: bytes, *, limits: HostLimits | None = None
) -> tuple[list[NDArray[Any]], list[dict[str, Any]]]:
    """The complete pages at the start of a TIFF that was cut off (a broken-off burst).

    Pages are laid out front to back (IFD, description, pixels), so every page whose
    pixels arrived is read; the rest is left out, and so is anything past ``limits``.
    """
    limits = limits or HostLimits()
    images: list[NDArray[Any]] = []
    metadata: list[dict[str, Any]] = []
    if len(data) < 8 or data[:4] != b"II*\x00":
        return images, metadata
    offset = int.from_bytes(data[4:8], "little")
    while offset and offset + 2 <= len(data) and len(images) < limits.burst_frames:
        n = int.from_bytes(data[offset : offset + 2], "little")
        end = offset + 2 + 12 * n + 4
        if end > len(data):
            break
        tags: dict[int, tuple[int, int]] = {}
        for i in range(n):
            entry = data[offset + 2 + 12 * i : offset + 14 + 12 * i]
            tag, kind, count = struct.unpack("<HHI", entry[:8])
            value = struct.unpack("<H", entry[8:10])[0] if kind == 3 else _u32(entry[8:12])
            tags[tag] = (count, value)
        try:
            width, height = tags[256][1], tags[257][1]
            desc_count, desc_at = tags[270]
            strip_at, nbytes = tags[273][1], tags[279][1]
        except KeyError:
            break
        if strip_at + nbytes > len(data) or nbytes != width * height * 2:
            break
        description = data[desc_at : desc_at + desc_count].rstrip(b"\x00")
        try:
            meta = strict_json.loads(description, what="", limit_bytes=limits.json_bytes)
        except ValueError:
            break
        if not isinstance(meta, dict):
            break
        meta.pop("shape", None)
        pixels = np.frombuffer(data, dtype="<u2", count=width * height, offset=strip_at)
        images.append(pixels.reshape(height, width).copy())
        metadata.append(meta)
        offset = _u32(data[end - 4 : end])
    return images, metadata


def _u32(b: bytes) -> int:
    return int.from_bytes(b, "little")
