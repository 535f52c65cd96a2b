"""The point-cloud PLY: round trips, foreign files, and bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from elphel_host.cloud.ply import PointCloud, ply_bytes, read_ply, write_ply
from elphel_host.errors import InputFormatError


def _cloud(n: int = 50, seed: int = 0) -> PointCloud:
    rng = np.random.default_rng(seed)
    return PointCloud(
        rng.normal(0, 1000, (n, 3)).astype(np.float32),
        rng.uniform(0, 1, n).astype(np.float32),
        rng.integers(0, 256, (n, 3), dtype=np.uint8),
        {"distance": rng.uniform(0, 5, n).astype(np.float32)},
    )


def test_round_trip(tmp_path: Path) -> None:
    c = _cloud()
    back = read_ply(write_ply(tmp_path / "c.ply", c, comments=("made by a test",)))
    assert np.array_equal(back.xyz, c.xyz)
    assert back.strength is not None and c.strength is not None
    assert np.array_equal(back.strength, c.strength)
    assert back.rgb is not None and np.array_equal(back.rgb, c.rgb)
    assert np.array_equal(back.scalars["distance"], c.scalars["distance"])
    assert not list(tmp_path.glob(".*part*"))


def test_header_is_the_documented_one() -> None:
    c = PointCloud(np.zeros((2, 3), np.float32))
    data = ply_bytes(c)
    header, body = data.split(b"end_header\n")
    assert header.decode().splitlines() == [
        "ply",
        "format binary_little_endian 1.0",
        "element vertex 2",
        "property float x",
        "property float y",
        "property float z",
        "property float strength",
        "property uchar red",
        "property uchar green",
        "property uchar blue",
    ]
    assert len(body) == 2 * (4 * 4 + 3)
    # defaults: strength 1, mid grey
    rec = np.frombuffer(body, dtype=[("p", "<f4", 4), ("c", "u1", 3)])
    assert np.all(rec["p"][:, 3] == 1.0) and np.all(rec["c"] == 128)


def test_reads_ascii_and_big_endian_with_faces(tmp_path: Path) -> None:
    ascii_ply = (
        "ply\nformat ascii 1.0\ncomment from another tool\nelement vertex 3\n"
        "property double x\nproperty double y\nproperty double z\nproperty float nx\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "1 2 3 0.5\n4 5 6 0.5\n7 8 9 0.5\n3 0 1 2\n"
    )
    (tmp_path / "a.ply").write_text(ascii_ply)
    a = read_ply(tmp_path / "a.ply")
    assert a.xyz.tolist() == [[1, 2, 3], [4, 5, 6], [7, 8, 9]]
    assert a.strength is None and a.rgb is None and set(a.scalars) == {"nx"}
    big = np.array([(1.5, -2.0, 3.25)], dtype=[("x", ">f4"), ("y", ">f4"), ("z", ">f4")])
    header = "ply\nformat binary_big_endian 1.0\nelement vertex 1\n" + "".join(
        f"property float {a}\n" for a in "xyz"
    )
    (tmp_path / "b.ply").write_bytes((header + "end_header\n").encode() + big.tobytes())
    assert read_ply(tmp_path / "b.ply").xyz.tolist() == [[1.5, -2.0, 3.25]]


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"PK\x03\x04", "not a PLY"),
        (b"ply\nformat binary_little_endian 1.0\nelement vertex 1\n", "no end_header"),
        (b"ply\nformat foo 1.0\nelement vertex 0\nend_header\n", "format 'foo'"),
        (
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
            b"end_header\n1 2\n",
            "no z property",
        ),
        (
            b"ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\n"
            b"property float y\nproperty float z\nend_header\n" + b"\0" * 13,
            "truncated: 2 vertices need 24 bytes, 13 present",
        ),
        (
            b"ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int vertex_indices\n"
            b"end_header\n",
            "first PLY element must be 'vertex'",
        ),
    ],
)
def test_bad_files(tmp_path: Path, content: bytes, message: str) -> None:
    (tmp_path / "bad.ply").write_bytes(content)
    with pytest.raises(InputFormatError, match=message):
        read_ply(tmp_path / "bad.ply")


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputFormatError, match="no such file"):
        read_ply(tmp_path / "nope.ply")


def test_bad_fields() -> None:
    with pytest.raises(InputFormatError, match=r"xyz must have shape \(N, 3\)"):
        PointCloud(np.zeros((3, 2), np.float32))
    with pytest.raises(InputFormatError, match="float32"):
        PointCloud(np.zeros((3, 3)))
    with pytest.raises(InputFormatError, match="scalar field name 'red'"):
        PointCloud(np.zeros((3, 3), np.float32), scalars={"red": np.zeros(3, np.float32)})
