"""The point-cloud file: binary little-endian PLY with fixed vertex fields.

Written: ``x y z`` (float32, millimetres), ``strength`` (float32), ``red green blue``
(uint8), then any extra float32 scalar fields (``distance`` in a compared cloud), one
``vertex`` element and nothing else. Read: any PLY (ascii, binary little- or big-endian)
whose first element is ``vertex`` with scalar properties including ``x y z``; the fixed
fields are taken when present, other scalar vertex properties become extra fields, and
elements after the vertices (faces of a mesh) are ignored. The format is described in
docs/formats.md (Point clouds).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from elphel_host.errors import InputFormatError
from elphel_host.fileio import replacing

F32 = NDArray[np.float32]

# PLY scalar type names (both spellings) -> NumPy type without byte order.
_PLY_TYPES = {
    name: code
    for names, code in (
        (("char", "int8"), "i1"),
        (("uchar", "uint8"), "u1"),
        (("short", "int16"), "i2"),
        (("ushort", "uint16"), "u2"),
        (("int", "int32"), "i4"),
        (("uint", "uint32"), "u4"),
        (("float", "float32"), "f4"),
        (("double", "float64"), "f8"),
    )
    for name in names
}
_COLOUR = ("red", "green", "blue")
_FIXED = ("x", "y", "z", "strength", *_COLOUR)


@dataclass(frozen=True, eq=False)
class PointCloud:
    """Points with optional strength, colour and extra scalar fields.

    Attributes
    ----------
    xyz
        ``(N, 3)`` float32, millimetres.
    strength
        ``(N,)`` float32 or None (written as 1.0).
    rgb
        ``(N, 3)`` uint8 or None (written as mid grey).
    scalars
        Extra per-point float32 fields by name (``distance``, ...).
    """

    xyz: F32
    strength: F32 | None = None
    rgb: NDArray[np.uint8] | None = None
    scalars: Mapping[str, F32] = field(default_factory=dict)

    def __post_init__(self) -> None:
        xyz = self.xyz
        if xyz.ndim != 2 or xyz.shape[1] != 3:
            raise InputFormatError(f"xyz must have shape (N, 3), got {xyz.shape}")
        if xyz.dtype != np.float32:
            raise InputFormatError(f"xyz must be float32, got {xyz.dtype}")
        n = xyz.shape[0]
        if self.strength is not None and self.strength.shape != (n,):
            raise InputFormatError(f"strength must have shape ({n},), got {self.strength.shape}")
        if self.rgb is not None and (self.rgb.shape != (n, 3) or self.rgb.dtype != np.uint8):
            raise InputFormatError(
                f"rgb must be uint8 of shape ({n}, 3), got {self.rgb.dtype} {self.rgb.shape}"
            )
        for name, values in self.scalars.items():
            if name in _FIXED or not name.isidentifier():
                raise InputFormatError(
                    f"scalar field name {name!r}; allowed: an identifier "
                    f"other than {', '.join(_FIXED)}"
                )
            if np.shape(values) != (n,):
                raise InputFormatError(
                    f"scalar field {name!r} must have shape ({n},), got {np.shape(values)}"
                )

    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    def subset(self, keep: NDArray[np.bool_]) -> PointCloud:
        """The points where ``keep`` is true, every field kept."""
        return PointCloud(
            self.xyz[keep],
            None if self.strength is None else self.strength[keep],
            None if self.rgb is None else self.rgb[keep],
            {k: np.asarray(v)[keep] for k, v in self.scalars.items()},
        )


def _vertex_dtype(scalars: Mapping[str, F32]) -> np.dtype[np.void]:
    fields = [(n, "<f4") for n in ("x", "y", "z", "strength")]
    fields += [(c, "u1") for c in _COLOUR]
    fields += [(n, "<f4") for n in scalars]
    return np.dtype(fields)


def ply_bytes(cloud: PointCloud, *, comments: tuple[str, ...] = ()) -> bytes:
    """The cloud as a binary little-endian PLY file."""
    dtype = _vertex_dtype(cloud.scalars)
    rec = np.zeros(len(cloud), dtype=dtype)
    for i, axis in enumerate("xyz"):
        rec[axis] = cloud.xyz[:, i]
    rec["strength"] = 1.0 if cloud.strength is None else cloud.strength
    for i, c in enumerate(_COLOUR):
        rec[c] = 128 if cloud.rgb is None else cloud.rgb[:, i]
    for name, values in cloud.scalars.items():
        rec[name] = values
    lines = ["ply", "format binary_little_endian 1.0"]
    lines += [f"comment {c}" for c in comments if "\n" not in c]
    lines.append(f"element vertex {len(cloud)}")
    for name in dtype.names or ():
        lines.append(f"property {'uchar' if name in _COLOUR else 'float'} {name}")
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii") + rec.tobytes()


def write_ply(path: str | Path, cloud: PointCloud, *, comments: tuple[str, ...] = ()) -> Path:
    """Write ``cloud`` to ``path`` (atomically: the file appears whole or not at all)."""
    path = Path(path)
    data = ply_bytes(cloud, comments=comments)
    with replacing(path, sync=True) as tmp:
        tmp.write_bytes(data)
    return path


@dataclass(frozen=True)
class _Element:
    name: str
    count: int
    properties: list[tuple[str, str]]  # (name, numpy code); list properties have code "list"


def _parse_header(data: bytes, source: str) -> tuple[str, list[_Element], int]:
    if not data.startswith(b"ply"):
        raise InputFormatError(f"{source}: not a PLY file (no 'ply' magic)")
    end = data.find(b"end_header")
    if end < 0:
        raise InputFormatError(f"{source}: PLY header has no end_header")
    body = data.find(b"\n", end) + 1
    if body == 0:
        raise InputFormatError(f"{source}: PLY header has no line end after end_header")
    fmt = ""
    elements: list[_Element] = []
    for raw in data[:end].decode("ascii", "replace").splitlines()[1:]:
        words = raw.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and len(words) >= 2:
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3:
            try:
                elements.append(_Element(words[1], int(words[2]), []))
            except ValueError as e:
                raise InputFormatError(f"{source}: bad PLY element line {raw!r}") from e
        elif words[0] == "property" and elements:
            if words[1] == "list":
                elements[-1].properties.append((words[-1], "list"))
            elif len(words) == 3 and words[1] in _PLY_TYPES:
                elements[-1].properties.append((words[2], _PLY_TYPES[words[1]]))
            else:
                raise InputFormatError(f"{source}: bad PLY property line {raw!r}")
        else:
            raise InputFormatError(f"{source}: unexpected PLY header line {raw!r}")
    allowed = ("ascii", "binary_little_endian", "binary_big_endian")
    if fmt not in allowed:
        raise InputFormatError(f"{source}: PLY format {fmt!r}; allowed: {', '.join(allowed)}")
    return fmt, elements, body


def read_ply(path: str | Path) -> PointCloud:
    """Read a PLY point cloud (see the module docstring for what is accepted).

    Raises
    ------
    InputFormatError
        When the file is not a PLY, has no vertex element with x, y, z first, or is truncated.
    """
    source = str(path)
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError as e:
        raise InputFormatError(f"{source}: no such file") from e
    fmt, elements, body = _parse_header(data, source)
    if not elements or elements[0].name != "vertex":
        raise InputFormatError(f"{source}: the first PLY element must be 'vertex'")
    vertex = elements[0]
    names = [n for n, _ in vertex.properties]
    if any(code == "list" for _, code in vertex.properties):
        raise InputFormatError(f"{source}: vertex has list properties; only scalars are read")
    missing = [a for a in "xyz" if a not in names]
    if missing:
        raise InputFormatError(f"{source}: vertex has no {', '.join(missing)} property")
    n = vertex.count
    if fmt == "ascii":
        lines = data[body:].split(b"\n", n)[:n]
        try:
            table = np.loadtxt(lines, ndmin=2, dtype=np.float64) if n else np.zeros((0, len(names)))
        except ValueError as e:
            raise InputFormatError(f"{source}: bad ASCII vertex data ({e})") from e
        if table.shape != (n, len(names)):
            raise InputFormatError(f"{source}: expected {n} vertices of {len(names)} values")
        columns = {name: table[:, i] for i, name in enumerate(names)}
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        dtype = np.dtype([(name, order + code) for name, code in vertex.properties])
        if len(data) - body < n * dtype.itemsize:
            raise InputFormatError(
                f"{source}: truncated: {n} vertices need {n * dtype.itemsize} bytes, "
                f"{len(data) - body} present"
            )
        rec = np.frombuffer(data, dtype=dtype, count=n, offset=body)
        columns = {name: rec[name] for name in names}
    xyz = np.stack([columns[a] for a in "xyz"], axis=1).astype(np.float32)
    strength = columns["strength"].astype(np.float32) if "strength" in columns else None
    rgb = None
    if all(c in columns for c in _COLOUR):
        rgb = np.stack([columns[c] for c in _COLOUR], axis=1).clip(0, 255).astype(np.uint8)
    scalars = {k: v.astype(np.float32) for k, v in columns.items() if k not in _FIXED}
    return PointCloud(xyz, strength, rgb, scalars)
