"""One recorded frame: decoded from its file, written as the project's 16-bit TIFF.

The TIFF is what an elphel-camd capture is: one 16-bit page whose ImageDescription is the
frame's metadata as JSON (tifffile ``description=``, no tifffile metadata of its own).
"""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
from numpy.typing import NDArray

from elphel_host import strict_json
from elphel_host.camera.jp4 import decode_jp4
from elphel_host.errors import Jp4FormatError
from elphel_host.fileio import replacing


def read_recording(path: Path) -> tuple[NDArray[np.uint16], dict[str, Any]]:
    """Decode one recorded frame; errors name the file (`Jp4FormatError` or `OSError`)."""
    try:
        data = path.read_bytes()
    except OSError as e:
        raise OSError(f"{path}: cannot be read ({e.strerror or e})") from e
    try:
        image, meta = decode_jp4(data)
    except Jp4FormatError as e:
        raise Jp4FormatError(f"{path}: {e}") from e
    meta["recorded_file"] = path.name
    return image, meta


def tiff_bytes(image: NDArray[np.uint16], metadata: dict[str, Any]) -> bytes:
    """A one-page 16-bit TIFF with the JSON metadata in ImageDescription, as captures have."""
    buffer = io.BytesIO()
    description = strict_json.dumps(metadata, what="the frame's metadata")
    tifffile.imwrite(buffer, image, description=description, metadata=None)
    return buffer.getvalue()


def write_frame_tiff(path: Path, image: NDArray[np.uint16], metadata: dict[str, Any]) -> Path:
    """Write ``path`` atomically: a 16-bit TIFF with the JSON metadata."""
    description = strict_json.dumps(metadata, what=f"{path}'s metadata")
    with replacing(path, keep_suffix=True) as tmp:
        tifffile.imwrite(tmp, image, description=description, metadata=None)
    return path


def complete_tiff_metadata(path: Path) -> dict[str, Any] | None:
    """The JSON metadata of a TIFF that is whole (all its data inside the file), else None."""
    try:
        with tifffile.TiffFile(path) as tif:
            page = tif.pages.first
            end = max(o + n for o, n in zip(page.dataoffsets, page.databytecounts, strict=True))
            if end > path.stat().st_size:
                return None
            meta = json.loads(page.description) if page.description else {}
    except Exception:  # a damaged or foreign file: convert it again
        return None
    return meta if isinstance(meta, dict) else None
