"""DSI and ML_DATA files: the tile processor's output stacks.

* DSI (docs/tile-processor.md, Files): ImageJ float32 stack, one slice per layer,
  tiles-Y x tiles-X, slice labels naming the layers; the ImageJ "info" string holds
  Elphel-style XML properties with the tile size, stride and geometry.
* ML_DATA (Elphel's version 1.1, 32-bit variant): per layer one image of
  9 x 9 pixels per tile (the centre of the 15 x 15 correlation), layers ``diagm-pair``,
  ``diago-pair``, ``hor-pairs``, ``vert-pairs`` and ``other`` (target disparity at
  tile-local index 0, ground-truth disparity at 2 and its strength at 4).
"""

from __future__ import annotations

import json
import struct
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np
import tifffile
from numpy.typing import NDArray

from elphel_host.errors import InputFormatError
from elphel_host.fileio import replacing
from elphel_host.tp.geometry import QuadGeometry

F32 = NDArray[np.float32]

ML_LAYERS = ("diagm-pair", "diago-pair", "hor-pairs", "vert-pairs", "other")
ML_HALF = 4  # 9x9 per tile
ML_OTHER_TARGET, ML_OTHER_GTRUTH, ML_OTHER_GTRUTH_STRENGTH = 0, 2, 4


def properties_xml(props: dict[str, Any]) -> str:
    """Elphel-style ImageJ info: ``<?xml ...?><properties><KEY>value</KEY>...</properties>``."""
    root = ET.Element("properties")
    for key, value in props.items():
        ET.SubElement(root, key).text = (
            value if isinstance(value, str) else json.dumps(value, allow_nan=False)
        )
    return '<?xml version="1.0" encoding="UTF-8"?>' + ET.tostring(root, encoding="unicode")


def parse_properties(info: str) -> dict[str, str]:
    """Inverse of :func:`properties_xml` (values as strings)."""
    start = info.find("<properties")
    if start < 0:
        return {}
    root = ET.fromstring(info[start:])
    return {child.tag: child.text or "" for child in root}


def write_dsi(
    path: str | Path,
    layers: dict[str, F32],
    *,
    image_size: tuple[int, int],
    geometry: QuadGeometry,
    bayer: str | None,
    extra: dict[str, Any] | None = None,
) -> None:
    """Write a DSI as an ImageJ float32 stack (docs/tile-processor.md, Files).

    Parameters
    ----------
    layers
        Name -> ``(tiles_y, tiles_x)`` array; slice order = dict order.
    image_size
        (width, height) of the source images.
    """
    names = list(layers)
    if not names:
        raise ValueError("layers is empty; at least 'disparity' and 'strength' are expected")
    shapes = {np.shape(layers[n]) for n in names}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"all layers must share one 2-D shape, got {sorted(map(str, shapes))}")
    stack = np.stack([np.asarray(layers[n], dtype=np.float32) for n in names])
    ty, tx = stack.shape[1:]
    props: dict[str, Any] = {
        "VERSION": "1.0",
        "tileSize": 16,
        "tileStride": 8,
        "tilesX": tx,
        "tilesY": ty,
        "imageWidth": image_size[0],
        "imageHeight": image_size[1],
        "tileCentre": "(8*tx+4, 8*ty+4)",
        "tileCovers": "8*tx-4 .. 8*tx+11",
        "bayer": bayer if bayer is not None else "null",
        "cameraPositions": [list(p) for p in geometry.positions],
        "pairs": [list(p) for p in geometry.pairs],
        "disparityConvention": "camera i sees p - D*position_i (D: shift across one side)",
        "layers": names,
    }
    props.update(extra or {})
    # through a temporary name: a DSI under its final name is always complete
    with replacing(path, keep_suffix=True) as tmp:
        tifffile.imwrite(
            tmp, stack, imagej=True, metadata={"Labels": names, "Info": properties_xml(props)}
        )


# A damaged TIFF fails deep inside tifffile with any of these (RuntimeError: for one,
# pages whose shapes do not match their first page's, "incompatible keyframe").
DAMAGED_TIFF_ERRORS = (
    tifffile.TiffFileError,
    struct.error,
    EOFError,
    OSError,
    ValueError,
    RuntimeError,
    KeyError,
    IndexError,
    TypeError,
    AttributeError,
    AssertionError,
    MemoryError,
)


def read_dsi(path: str | Path) -> tuple[dict[str, F32], dict[str, str]]:
    """Read a DSI written by :func:`write_dsi`: (layers, properties).

    Raises `InputFormatError` naming the file for anything that is not such a TIFF.
    """
    try:
        with tifffile.TiffFile(path) as tif:
            data = tif.asarray()
            meta = tif.imagej_metadata or {}
    except FileNotFoundError:
        raise
    except DAMAGED_TIFF_ERRORS as e:
        raise InputFormatError(f"{path}: not a readable DSI TIFF ({e})") from e
    labels = meta.get("Labels")
    if isinstance(labels, str):
        labels = [labels]
    if data.ndim == 2:
        data = data[None]
    if data.ndim != 3:
        raise InputFormatError(f"{path}: shape={data.shape}; allowed: slices of 2-D layers")
    if not isinstance(labels, list) or len(labels) != data.shape[0]:
        raise InputFormatError(f"{path}: ImageJ slice labels missing or not one per slice")
    try:
        props = parse_properties(str(meta.get("Info", "")))
    except ET.ParseError as e:
        raise InputFormatError(f"{path}: Info properties are not XML ({e})") from e
    return {str(n): data[i].astype(np.float32) for i, n in enumerate(labels)}, props


def ml_data_name(timestamp: str, *, fat_zero: float, offset: float = 0.0) -> str:
    """Elphel's ML_DATA file name for a 32-bit hor/vert export."""
    return f"{timestamp}-ML_DATA-32B-O-FZ{fat_zero:g}-OFFS{offset:g}.tiff"


def _combine(a: F32, b: F32, offset: float) -> F32:
    if offset < 0:
        out: F32 = (0.5 * (a + b)).astype(np.float32)
        return out
    prod = np.maximum(a + offset, 0) * np.maximum(b + offset, 0)
    res: F32 = (np.sqrt(prod) - offset).astype(np.float32)
    return res


def write_ml_data(
    path: str | Path,
    correlations: F32,
    target: F32,
    *,
    ground_truth: F32 | None = None,
    ground_truth_strength: F32 | None = None,
    combine_offset: float = 0.1,
    extra: dict[str, Any] | None = None,
) -> None:
    """Write correlation tiles in the ML_DATA layout (32-bit floats, version 1.1).

    Parameters
    ----------
    correlations
        ``(tiles_y, tiles_x, 6, 15, 15)`` pair correlations in native orientation (pairs in
        the order of ``geometry.PAIRS``).
    target
        ``(tiles_y, tiles_x)`` target disparity of the correlations.
    ground_truth, ground_truth_strength
        Optional ``(tiles_y, tiles_x)`` truth for training (NaN when absent).
    combine_offset
        Offset of the shifted geometric mean combining the two horizontal (vertical) pairs;
        negative: plain average.
    """
    c = np.asarray(correlations, dtype=np.float32)
    if c.ndim != 5 or c.shape[2] != 6 or c.shape[3:] != (15, 15):
        raise ValueError(f"correlations must have shape (ty, tx, 6, 15, 15), got {c.shape}")
    ty, tx = c.shape[:2]
    centre = c[:, :, :, 7 - ML_HALF : 8 + ML_HALF, 7 - ML_HALF : 8 + ML_HALF]  # (ty, tx, 6, 9, 9)
    layers = [
        centre[:, :, 4],
        centre[:, :, 5],
        _combine(centre[:, :, 0], centre[:, :, 1], combine_offset),
        _combine(centre[:, :, 2], centre[:, :, 3], combine_offset),
    ]
    layers.append(_other_layer((ty, tx), target, ground_truth, ground_truth_strength))
    side = 2 * ML_HALF + 1
    images = np.stack([lay.transpose(0, 2, 1, 3).reshape(ty * side, tx * side) for lay in layers])
    corr = np.stack(layers[:4])
    props: dict[str, Any] = {
        "VERSION": "1.1",
        "tileWidth": side,
        "ML_OTHER_TARGET": ML_OTHER_TARGET,
        "ML_OTHER_GTRUTH": ML_OTHER_GTRUTH,
        "ML_OTHER_GTRUTH_STRENGTH": ML_OTHER_GTRUTH_STRENGTH,
        "data_min": float(np.nanmin(corr)),
        "data_max": float(np.nanmax(corr)),
    }
    props.update(extra or {})
    tifffile.imwrite(
        path,
        images.astype(np.float32),
        imagej=True,
        metadata={"Labels": list(ML_LAYERS), "Info": properties_xml(props)},
    )


def _other_layer(
    tiles: tuple[int, int], target: F32, ground_truth: F32 | None, strength: F32 | None
) -> F32:
    """The ``other`` layer: per tile 9x9 NaN but the target and the optional ground truth."""
    ty, tx = tiles
    other = np.full((ty, tx, 9, 9), np.nan, dtype=np.float32)
    flat = other.reshape(ty, tx, 81)
    flat[:, :, ML_OTHER_TARGET] = target
    if ground_truth is not None:
        flat[:, :, ML_OTHER_GTRUTH] = ground_truth
    if strength is not None:
        flat[:, :, ML_OTHER_GTRUTH_STRENGTH] = strength
    return other


def read_ml_data(path: str | Path) -> tuple[F32, F32, dict[str, str]]:
    """Read an ML_DATA file: correlations ``(ty, tx, 9, 9, 4)``, other ``(ty, tx, 3)``, properties.

    ``other`` holds the target disparity, the ground-truth disparity and its strength.
    """
    layers, props = read_dsi(path)

    def number(key: str, default: int, minimum: int) -> int:
        text = props.get(key, default)
        try:
            value = int(text)
        except ValueError:
            raise InputFormatError(f"{path}: {key}={text!r}; allowed: an integer") from None
        if value < minimum:
            raise InputFormatError(f"{path}: {key}={value}; allowed: >= {minimum}")
        return value

    side = number("tileWidth", 2 * ML_HALF + 1, 1)
    missing = [n for n in ML_LAYERS if n not in layers]
    if missing:
        raise InputFormatError(f"{path}: ML_DATA layers missing: {missing}")
    h, w = layers[ML_LAYERS[0]].shape
    if h % side or w % side:
        raise InputFormatError(f"{path}: layer size {w}x{h} is not a multiple of tileWidth={side}")
    ty, tx = h // side, w // side

    def tiles(img: F32) -> F32:
        out: F32 = img.reshape(ty, side, tx, side).transpose(0, 2, 1, 3)
        return out

    corr = np.stack([tiles(layers[n]) for n in ML_LAYERS[:4]], axis=-1)
    other = tiles(layers["other"]).reshape(ty, tx, side * side)
    idx = []
    for key, default in (
        ("ML_OTHER_TARGET", 0),
        ("ML_OTHER_GTRUTH", 2),
        ("ML_OTHER_GTRUTH_STRENGTH", 4),
    ):
        i = number(key, default, 0)
        if i >= side * side:
            raise InputFormatError(
                f"{path}: {key}={i}; allowed: < {side * side} (tileWidth squared)"
            )
        idx.append(i)
    return corr.astype(np.float32), other[:, :, idx].astype(np.float32), props
