"""Cloud-to-cloud distances against brute force and known offsets; `elphel cloud compare`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from elphel_host.cli import main
from elphel_host.cloud.compare import compare_clouds, distance_stats, nearest_distances
from elphel_host.cloud.ply import PointCloud, read_ply, write_ply
from elphel_host.errors import InputFormatError


def _plane(step: float = 1.0, n: int = 101, z: float = 0.0) -> PointCloud:
    g = np.arange(n) * step
    x, y = np.meshgrid(g, g)
    return PointCloud(np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], 1).astype(np.float32))


def test_nearest_matches_brute_force() -> None:
    rng = np.random.default_rng(3)
    a = rng.uniform(0, 100, (300, 3))
    b = rng.uniform(0, 100, (500, 3))
    brute = np.sqrt(((a[:, None, :] - b[None]) ** 2).sum(-1)).min(1)
    assert np.allclose(nearest_distances(a, b, workers=2), brute, rtol=0, atol=1e-9)


def test_offset_plane_both_directions() -> None:
    ref = _plane()
    # compared: a plane 0.3 mm above the middle of the reference, half its size
    cmp_ = PointCloud(_plane(n=51).xyz + np.float32([25, 25, 0.3]))
    r = compare_clouds(cmp_, ref)
    assert r.forward.points == 51 * 51
    assert r.forward.mean_mm == pytest.approx(0.3, abs=1e-5)
    assert r.forward.max_mm == pytest.approx(0.3, abs=1e-5)
    assert r.forward.std_mm == pytest.approx(0.0, abs=1e-5)
    # reference -> compared: the uncovered rim is far away
    assert r.backward.points == 101 * 101
    assert r.backward.max_mm == pytest.approx(np.hypot(25.0, 25.0) + 0.0, abs=0.01)
    assert r.backward.median_mm > 1.0


def test_max_distance_counts_and_drops() -> None:
    d = np.array([0.1, 0.2, 0.3, 5.0, 9.0])
    s = distance_stats(d, max_distance_mm=1.0)
    assert (s.points, s.beyond) == (3, 2)
    assert s.mean_mm == pytest.approx(0.2) and s.max_mm == pytest.approx(0.3)
    assert s.median_mm == pytest.approx(0.2)
    full = distance_stats(d)
    assert full.p95_mm == pytest.approx(np.percentile(d, 95))
    assert full.to_json()["beyond"] == 0
    none = distance_stats(d, max_distance_mm=0.01)
    assert none.points == 0 and none.to_json()["mean_mm"] is None


def test_bad_input() -> None:
    empty = PointCloud(np.zeros((0, 3), np.float32))
    with pytest.raises(InputFormatError, match="reference cloud is empty"):
        compare_clouds(_plane(n=3), empty)
    with pytest.raises(InputFormatError, match="compared cloud is empty"):
        compare_clouds(empty, _plane(n=3))
    with pytest.raises(InputFormatError, match="max_distance_mm=0"):
        compare_clouds(_plane(n=3), _plane(n=3), max_distance_mm=0)
    bad = PointCloud(np.array([[np.nan, 0, 0]], np.float32))
    with pytest.raises(InputFormatError, match="non-finite"):
        compare_clouds(bad, _plane(n=3))


def test_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(0)
    ref = _plane(step=0.5, n=201)
    noisy = ref.xyz[::7].copy()
    noisy[:, 2] += rng.normal(0, 0.2, len(noisy)).astype(np.float32)
    noisy[:5, 2] += 50.0  # outliers
    write_ply(tmp_path / "ref.ply", ref)
    write_ply(tmp_path / "m.ply", PointCloud(noisy, np.ones(len(noisy), np.float32)))
    code = main(
        ["cloud", "compare", str(tmp_path / "m.ply"), str(tmp_path / "ref.ply"),
         "--max-distance", "5", "--out-dir", str(tmp_path / "o"), "--json"]
    )  # fmt: skip
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    f = out["compared_to_reference"]
    assert f["beyond"] == 5 and f["points"] == len(noisy) - 5
    # |N(0, 0.2)| has mean 0.2 sqrt(2/pi) = 0.16 (nearest points also shift it down a bit)
    assert 0.1 < f["mean_mm"] < 0.17 and f["max_mm"] < 1.0
    assert out["reference_points"] == 201 * 201
    coloured = read_ply(out["coloured_ply"])
    assert len(coloured) == len(noisy) and coloured.rgb is not None
    d = coloured.scalars["distance"]
    assert np.all(d[:5] > 49) and np.all(d[5:] < 1.0)
    # far points get the top of the colour map, near ones differ from them
    assert not np.array_equal(coloured.rgb[0], coloured.rgb[np.argmin(d)])
    with Image.open(out["histogram_png"]) as im:
        assert im.format == "PNG" and im.size[0] > 300


def test_cli_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "x.ply").write_bytes(b"nope")
    assert main(["cloud", "compare", str(tmp_path / "x.ply"), str(tmp_path / "x.ply")]) == 1
    assert "not a PLY" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["cloud", "compare", "a.ply", "b.ply", "--max-distance", "-1"])
    assert e.value.code == 2
