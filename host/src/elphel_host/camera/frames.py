"""Frames as the camera daemon sends them: TIFF bytes with JSON metadata, decoded.

A capture is one 16-bit TIFF whose ImageDescription is the frame's metadata (JSON, as
tifffile writes ``metadata=``); ``?count=N`` gives N consecutive frames as one multi-page
TIFF; photo-finish composites of consecutive frames join into one image with each row's
time.
"""

from __future__ import annotations

import io
import itertools
import json
from dataclasses import dataclass
from typing import Any

import numpy as np
import tifffile
from numpy.typing import NDArray

from elphel_host.errors import CameraClientError


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
    """Consecutive frames in one multi-page TIFF: images (N, H, W) and per-frame metadata."""

    tiff: bytes
    images: NDArray[np.uint16]
    metadata: list[dict[str, Any]]

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


def read_tiff_metadata(data: bytes | str) -> tuple[NDArray[Any], dict[str, Any]]:
    """Image and JSON metadata (ImageDescription) of a TIFF written by the daemon."""
    source: Any = io.BytesIO(data) if isinstance(data, bytes) else data
    with tifffile.TiffFile(source) as tif:
        image = tif.asarray()
        description = tif.pages.first.description
    try:
        metadata = json.loads(description) if description else {}
    except json.JSONDecodeError as e:
        raise CameraClientError(f"TIFF ImageDescription is not JSON metadata: {e}") from e
    metadata.pop("shape", None)
    return image, metadata


def read_tiff_pages(data: bytes) -> tuple[NDArray[Any], list[dict[str, Any]]]:
    """Images (N, H, W) and each page's JSON metadata of a multi-page TIFF from the daemon."""
    with tifffile.TiffFile(io.BytesIO(data)) as tif:
        pages = [tif.pages[i] for i in range(len(tif.pages))]
        metadata = []
        for page in pages:
            meta = json.loads(page.description)  # type: ignore[union-attr]
            meta.pop("shape", None)
            metadata.append(meta)
        images = np.stack([page.asarray() for page in pages])
    return images, metadata


# Older names, kept for scripts: the multi-page capture was ``Burst`` (a burst directory is
# elphel_host.burst.io.Burst) and its decoder ``read_burst``.
Burst = CapturedBurst
read_burst = read_tiff_pages
