from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile

from elphel_host.burst.io import read_burst, write_burst
from elphel_host.errors import InputFormatError


def _frames(n=3, shape=(8, 10)):
    rng = np.random.default_rng(0)
    return [rng.integers(0, 4096, shape, dtype=np.uint16) for _ in range(n)]


def test_round_trip(tmp_path):
    frames = _frames()
    infos = [
        {"stage_mm": 0.01 * i, "caliper_mm": 0.011 * i, "frame": 100 + i, "timestamp_ns": 10**9 * i}
        for i in range(3)
    ]
    write_burst(
        tmp_path,
        frames,
        infos=infos,
        bayer="GRBG",
        optics={"focal_length_mm": 35.0, "pixel_pitch_um": 2.2, "object_distance_mm": 500.0},
        stage={"mm_per_step": 0.008778, "axis_angle_deg": 26.57},
        extra={"note": "x"},
    )
    b = read_burst(tmp_path)
    assert b.frames.dtype == np.uint16 and b.frames.shape == (3, 8, 10)
    assert all(np.array_equal(a, c) for a, c in zip(b.frames, frames, strict=True))
    assert b.infos[2].file == "frames/0002.tif" and b.infos[2].frame == 102
    assert b.bayer == "GRBG" and b.optics["pixel_pitch_um"] == 2.2
    assert b.stage["mm_per_step"] == 0.008778 and b.extra == {"note": "x"}
    prior = b.stage_prior_px()
    assert prior is not None and prior[0] == (0.0, 0.0)
    assert prior[1][1] > 0 and prior[1][0] / prior[1][1] == pytest.approx(0.5, rel=1e-3)


def _manifest(tmp_path, **change):
    write_burst(tmp_path, _frames())
    m = json.loads((tmp_path / "manifest.json").read_text())
    m.update(change)
    (tmp_path / "manifest.json").write_text(json.dumps(m))


@pytest.mark.parametrize(
    ("change", "needle"),
    [
        ({"version": 2}, "version=2; allowed: 1"),
        ({"bayer": "RGBX"}, "bayer='RGBX'; allowed: null or one of"),
        ({"frames": []}, "frames=[]; allowed: a non-empty list"),
        (
            {"frames": [{"file": "frames/0009.tif"}]},
            "frames[0].file='frames/0009.tif' does not exist",
        ),
        ({"frames": [{"file": "../x.tif"}]}, "allowed: a path inside the burst directory"),
        ({"frames": [{"file": "frames/0000.tif", "stage_mm": "a"}]}, "frames[0].stage_mm='a'"),
        ({"optics": {"focal_length_mm": -1}}, "optics.focal_length_mm=-1.0; allowed: > 0"),
        ({"stage": {"speed": 1}}, "stage.speed=1; allowed: keys mm_per_step, axis_angle_deg"),
    ],
)
def test_manifest_validation_names_field(tmp_path, change, needle):
    _manifest(tmp_path, **change)
    with pytest.raises(InputFormatError) as e:
        read_burst(tmp_path)
    assert needle in str(e.value) and "manifest.json" in str(e.value)


def test_frame_validation(tmp_path):
    write_burst(tmp_path, _frames())
    tifffile.imwrite(tmp_path / "frames/0001.tif", np.zeros((8, 10), np.float32))
    with pytest.raises(InputFormatError, match=r"0001.tif: dtype='float32'; allowed: uint16"):
        read_burst(tmp_path)
    tifffile.imwrite(tmp_path / "frames/0001.tif", np.zeros((8, 12), np.uint16))
    with pytest.raises(InputFormatError, match=r"shape=\(8, 12\); allowed: \(8, 10\)"):
        read_burst(tmp_path)
    (tmp_path / "frames/0001.tif").write_bytes(b"not a tiff")
    with pytest.raises(InputFormatError, match="not a readable TIFF"):
        read_burst(tmp_path)


def test_missing_and_broken_manifest(tmp_path):
    with pytest.raises(InputFormatError, match=r"no manifest\.json"):
        read_burst(tmp_path)
    (tmp_path / "manifest.json").write_text("{")
    with pytest.raises(InputFormatError, match="not valid JSON"):
        read_burst(tmp_path)
