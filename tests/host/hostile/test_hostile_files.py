"""Crafted files: JP4 bombs, quad and burst directories that escape, lie or nest without end."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
import tifffile

from elphel_sim.jp4 import encode_jp4
from tests.host.hostile.crafted import nested_json
from tests.host.hostile.fakes import assert_one_line_failure, run_elphel

SEC = 1_700_000_000


def jp4(frame: int, *, claimed: tuple[int, int] | None = None) -> bytes:
    """A 96x64 JP4 frame; ``claimed``: its SOF says (width, height) instead."""
    mosaic = np.random.default_rng(frame).integers(0, 4096, (64, 96)).astype(np.uint16)
    data = encode_jp4(
        mosaic,
        bits=12,
        frame=frame,
        port=0,
        exposure_us=800,
        timestamp_ns=(SEC + frame) * 10**9,
        gamma=0.57,
    )
    if claimed is None:
        return data
    sof = data.index(b"\xff\xc0")
    size = struct.pack(">HH", claimed[1], claimed[0])
    return data[: sof + 5] + size + data[sof + 9 :]


def test_a_jp4_claiming_more_than_its_makernote_is_skipped(tmp_path: Path) -> None:
    src = tmp_path / "in"
    src.mkdir()
    for k in range(3):
        (src / f"{SEC + k}_000000_0.jp4").write_bytes(
            jp4(k, claimed=(13376, 13376) if k == 1 else None)
        )
    # A limit above the claim: the MakerNote's window alone must refuse it.
    env = {"ELPHEL_LIMIT_FRAME_PIXELS": "200000000"}
    run = run_elphel(["jp4", "convert", str(src), "--out", str(tmp_path / "out")], **env)
    errors = [line for line in run.stderr.splitlines() if line.startswith("elphel: ")]
    assert run.code == 1 and "Traceback" not in run.stderr
    assert len(errors) == 1, run.stderr
    assert f"{SEC + 1}_000000_0.jp4" in errors[0] and "13376x13376" in errors[0], errors
    assert "MakerNote's window is 96x64" in errors[0], errors
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        f"{SEC}_000000_0.tif",
        f"{SEC + 2}_000000_0.tif",
    ]


def quad_dir(root: Path, **changes: object) -> Path:
    """A valid 16x16 quad directory, with quad.json fields replaced by ``changes``."""
    root.mkdir(parents=True)
    cameras = []
    for i, pos in enumerate([(-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)]):
        tifffile.imwrite(root / f"cam{i}.tif", np.full((16, 16), 1000 + i, np.uint16))
        cameras.append({"file": f"cam{i}.tif", "position": list(pos)})
    doc = {"version": 1, "cameras": cameras, "bayer": None, **changes}
    (root / "quad.json").write_text(json.dumps(doc))
    return root


def _cameras(**per_camera: list[object]) -> list[dict[str, object]]:
    positions = [[-0.5, -0.5], [0.5, -0.5], [-0.5, 0.5], [0.5, 0.5]]
    cams: list[dict[str, object]] = [
        {"file": f"cam{i}.tif", "position": p} for i, p in enumerate(positions)
    ]
    for key, values in per_camera.items():
        for cam, value in zip(cams, values, strict=True):
            cam[key] = value
    return cams


@pytest.mark.parametrize(
    ("changes", "needle"),
    [
        (
            {"cameras": _cameras(file=["../outside.tif", "cam1.tif", "cam2.tif", "cam3.tif"])},
            "../outside.tif",
        ),
        (
            {"cameras": _cameras(file=["/etc/passwd", "cam1.tif", "cam2.tif", "cam3.tif"])},
            "/etc/passwd",
        ),
        ({"cameras": _cameras(position=[[0, 0]] * 4)}, "distinct positions"),
        ({"full_scale_dn": 1e-9}, "full_scale_dn=1e-09"),
        ({"full_scale_dn": 1e300}, "full_scale_dn=1e+300"),
    ],
)
def test_quad_json_that_lies(tmp_path: Path, changes: dict[str, object], needle: str) -> None:
    quad = quad_dir(tmp_path / "q", **changes)
    run = run_elphel(["tp", str(quad), "--out", str(tmp_path / "dsi.tif")])
    assert_one_line_failure(run, needle)
    assert not (tmp_path / "dsi.tif").exists()


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("1e999", "overflows"),
        ("NaN", "NaN"),
    ],
)
def test_non_finite_positions(tmp_path: Path, text: str, needle: str) -> None:
    quad = quad_dir(tmp_path / "q")
    doc = (quad / "quad.json").read_text().replace("[-0.5, -0.5]", f"[{text}, -0.5]", 1)
    (quad / "quad.json").write_text(doc)
    run = run_elphel(["tp", str(quad), "--out", str(tmp_path / "dsi.tif")])
    assert_one_line_failure(run, needle)


def test_a_link_out_of_the_quad_directory(tmp_path: Path) -> None:
    quad = quad_dir(tmp_path / "q")
    outside = tmp_path / "outside.tif"
    (quad / "cam0.tif").rename(outside)
    (quad / "cam0.tif").symlink_to(outside)
    run = run_elphel(["tp", str(quad), "--out", str(tmp_path / "dsi.tif")])
    assert_one_line_failure(run, "outside", "no links out of it")


def test_deeply_nested_quad_json(tmp_path: Path) -> None:
    quad = quad_dir(tmp_path / "q")
    (quad / "quad.json").write_text(nested_json(100_000))
    run = run_elphel(["tp", str(quad), "--out", str(tmp_path / "dsi.tif")])
    assert_one_line_failure(run, "quad.json", "nested")


def burst_dir(root: Path, entries: list[dict[str, object]] | str) -> Path:
    (root / "frames").mkdir(parents=True)
    tifffile.imwrite(root / "frames/0000.tif", np.zeros((16, 16), np.uint16))
    text = entries if isinstance(entries, str) else json.dumps({"version": 1, "frames": entries})
    (root / "manifest.json").write_text(text)
    return root


@pytest.mark.parametrize(
    ("entries", "env", "needle"),
    [
        (nested_json(100_000), {}, "nested"),
        ([{"file": "frames/0000.tif"}] * 20_000, {}, "20000 frames; limit manifest_frames = 10000"),
        ([{"file": "frames/0000.tif"}] * 50, {}, "50 frames name only 1 distinct files"),
        ([{"file": "../../etc/passwd"}], {}, "a path inside the burst directory"),
        (
            '{"version": 1, "frames": [{"file": "frames/0000.tif", "frame": Infinity}]}',
            {},
            "Infinity",
        ),
    ],
)
def test_burst_manifests_that_lie(
    tmp_path: Path, entries: list[dict[str, object]] | str, env: dict[str, str], needle: str
) -> None:
    burst = burst_dir(tmp_path / "b", entries)
    run = run_elphel(["mfsr", str(burst), "--scale", "2", "--out", str(tmp_path / "o.tif")], **env)
    assert_one_line_failure(run, needle)
    assert run.seconds < 10, run.seconds
