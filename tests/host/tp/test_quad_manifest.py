"""quad.json has one owner: QuadManifest round trips, old files still read, bad ones named."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from elphel_host.errors import InputFormatError
from elphel_host.fileio import replacing_directory
from elphel_host.tp.io import KernelFile, QuadManifest, quad_cameras, read_quad_dir, write_quad_dir

SQUARE = ((-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5))


def captured_doc() -> dict:
    """quad.json as `elphel tp capture` writes it (DESIGN 4.4 + the capture record)."""
    cams = [
        {
            "file": f"cam{i}.tif",
            "position": list(pos),
            "port": i,
            "sensor": "mt9p006",
            "frame": 87 + i,
            "timestamp_ns": 123,
            "params": {"EXPOS": 10000, "TRIG": 4},
        }
        for i, pos in enumerate(SQUARE)
    ]
    return {
        "version": 1,
        "cameras": cams,
        "bayer": "GRBG",
        "full_scale_dn": 4095,
        "optics": {"baseline_mm": 150.0},
        "capture": {"camera_url": "http://h:1", "trigger": {"master": 0}},
    }


def test_a_captured_manifest_round_trips_with_its_order() -> None:
    doc = captured_doc()
    manifest = QuadManifest.from_json(doc)
    assert manifest.positions == SQUARE and manifest.bayer == "GRBG"
    assert manifest.cameras[2].fields["port"] == 2 and "capture" in manifest.extra
    back = manifest.to_json()
    assert back == doc
    assert list(back) == list(doc) and list(back["cameras"][0]) == list(doc["cameras"][0])


def test_the_minimal_old_form_still_reads_and_writes_the_same() -> None:
    doc = {
        "version": 1,
        "cameras": [{"file": f"cam{i}.tif", "position": list(p)} for i, p in enumerate(SQUARE)],
        "bayer": None,
    }
    manifest = QuadManifest.from_json(doc)
    assert manifest.full_scale_dn is None and manifest.kernels is None and manifest.optics is None
    assert manifest.to_json() == doc


def test_written_directory_reads_back(tmp_path: Path) -> None:
    images = (np.arange(4 * 16 * 24, dtype=np.uint16).reshape(4, 16, 24) * 7) % 4096
    kernels = np.zeros((4, 1, 1, 1, 15, 15), dtype=np.float32)
    kernels[..., 7, 7] = 1.0
    manifest = QuadManifest(
        cameras=quad_cameras(SQUARE),
        full_scale_dn=4095,
        kernels=KernelFile("kernels.npy", 16, target_sigma_px=1.3),
        extra={"note": "test"},
    )
    write_quad_dir(tmp_path, manifest, list(images), kernels=kernels)
    assert json.loads((tmp_path / "quad.json").read_text()) == manifest.to_json()
    assert manifest.to_json()["kernels"] == {
        "file": "kernels.npy",
        "step": 16,
        "target_sigma_px": 1.3,
    }
    qs = read_quad_dir(tmp_path)
    assert qs.manifest == QuadManifest.from_json(manifest.to_json())
    assert qs.full_scale_dn == 4095.0
    assert np.allclose(qs.quad.images * 4095, images)
    assert qs.quad.kernels is not None and qs.quad.kernels.shape == kernels.shape


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda m: m.update(optics=3), "optics=3; allowed: an object"),
        (
            lambda m: m.update(full_scale_dn=0),
            "full_scale_dn=0; allowed: a number in 0.001..4294967296",
        ),
        (lambda m: m.update(kernels={"step": 16}), "kernels=.*allowed"),
        (
            lambda m: m.update(kernels={"file": "k.npy", "target_sigma_px": 0}),
            "kernels.target_sigma_px=0; allowed: a number of sensor px > 0 and <= 5.0",
        ),
        (
            lambda m: m.update(kernels={"file": "k.npy", "target_sigma_px": "1"}),
            "kernels.target_sigma_px='1'",
        ),
        (lambda m: m["cameras"][0].pop("file"), r"cameras\[0\] needs 'file' and 'position'"),
        (lambda m: m["cameras"][3].update(position=[True, 0]), r"cameras\[3\].position"),
    ],
)
def test_bad_fields_are_named(edit, message: str) -> None:
    doc = captured_doc()
    edit(doc)
    with pytest.raises(InputFormatError, match=message):
        QuadManifest.from_json(doc, source="x/quad.json")


def test_extras_cannot_shadow_fields() -> None:
    with pytest.raises(ValueError, match="bayer"):
        QuadManifest(cameras=quad_cameras(SQUARE), extra={"bayer": "GRBG"})
    with pytest.raises(ValueError, match=r"\[.file.\] are attributes of QuadCamera"):
        quad_cameras(SQUARE, [{"file": "x"}] * 4)


def test_replacing_a_directory_is_all_or_nothing(tmp_path: Path) -> None:
    target = tmp_path / "quad"
    target.mkdir()
    (target / "old.txt").write_text("old")
    with pytest.raises(RuntimeError), replacing_directory(target) as tmp:
        (tmp / "new.txt").write_text("new")
        raise RuntimeError("halfway")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["quad"]
    assert (target / "old.txt").read_text() == "old"
    with replacing_directory(target) as tmp:
        (tmp / "new.txt").write_text("new")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["quad"]
    assert sorted(p.name for p in target.iterdir()) == ["new.txt"]
