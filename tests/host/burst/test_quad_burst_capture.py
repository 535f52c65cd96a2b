"""`capture_quad_burst`: four cameras per trigger into a quad-burst directory, resumable."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import tifffile

from elphel_host.burst.io import read_quad_burst
from elphel_host.burst.quad_capture import capture_quad_burst
from elphel_host.errors import InputFormatError
from elphel_host.stage.positioning import MoveResult
from elphel_host.tp.io import QuadManifest, quad_cameras

POSITIONS = [0.0, 1.5, 3.0, 4.5, 6.0]


class FakeQuad:
    """Four cameras of one trigger; raises KeyboardInterrupt before the move number ``fail_at``."""

    def __init__(self, fail_at: int | None = None) -> None:
        self.fail_at, self.moves, self.stopped, self.sets = fail_at, [], 0, 0
        self.at = 0.0

    def move(self, position_mm: float) -> MoveResult:
        if self.fail_at is not None and len(self.moves) == self.fail_at:
            raise KeyboardInterrupt
        self.moves.append(position_mm)
        self.at = position_mm
        return MoveResult(position_mm, round(position_mm, 2), 0, 1, position_mm)

    def acquire_quad(self) -> tuple[list[bytes], Any]:
        self.sets += 1
        stamp = 1_000_000 * self.sets
        tiffs = []
        for cam in range(4):
            buf = io.BytesIO()
            tifffile.imwrite(buf, np.full((8, 16), 100 * cam + int(self.at * 10), np.uint16))
            tiffs.append(buf.getvalue())
        fields = [{"port": c, "frame": 40 + self.sets, "timestamp_ns": stamp} for c in range(4)]
        manifest = QuadManifest(
            cameras=quad_cameras(((-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)), fields),
            bayer=None,
            full_scale_dn=4095,
            optics={"focal_length_mm": 4.5, "pixel_pitch_um": 2.2, "baseline_mm": 150.0},
        )
        return tiffs, manifest

    def stop(self) -> None:
        self.stopped += 1


def test_capture_interrupted_then_resumed(tmp_path: Path) -> None:
    out = tmp_path / "qb"
    first = FakeQuad(fail_at=3)
    with pytest.raises(KeyboardInterrupt):
        capture_quad_burst(
            first, POSITIONS, out, start_mm=10.0, top={"stage": {"axis_angle_deg": 14.0}}
        )
    assert first.stopped == 1 and first.sets == 3
    again = FakeQuad()
    result = capture_quad_burst(
        again, POSITIONS, out, start_mm=10.0, top={"stage": {"axis_angle_deg": 14.0}}
    )
    assert result.skipped == [0, 1, 2] and result.captured == [3, 4]
    assert again.moves == [14.5, 16.0]  # only the missing sets
    qb = read_quad_burst(out)
    assert qb.frames == 5
    for cam, burst in enumerate(qb.bursts):
        assert [e.index for e in burst.infos] == [0, 1, 2, 3, 4]
        assert [e.stage_mm for e in burst.infos] == [10.0 + p for p in POSITIONS]
        assert burst.stage["axis_angle_deg"] == 14.0
        # frame k of camera c was taken at position k
        assert [int(f[0, 0]) for f in burst.frames] == [
            100 * cam + int((10 + p) * 10) for p in POSITIONS
        ]
    assert qb.manifest.optics is not None and qb.manifest.optics["baseline_mm"] == 150.0
    stamps = {tuple(b.infos[k].timestamp_ns for b in qb.bursts) for k in range(5)}
    assert all(len(set(s)) == 1 for s in stamps)


def test_set_held_by_some_cameras_is_taken_again(tmp_path: Path) -> None:
    out = tmp_path / "qb"
    capture_quad_burst(FakeQuad(), POSITIONS[:2], out, start_mm=0.0)
    # a crash between the manifests: camera 3's manifest lacks set 1
    m = (out / "cam3" / "manifest.json").read_text()
    import json

    doc = json.loads(m)
    doc["frames"] = doc["frames"][:1]
    (out / "cam3" / "manifest.json").write_text(json.dumps(doc))
    eng = FakeQuad()
    result = capture_quad_burst(eng, POSITIONS[:2], out, start_mm=0.0)
    assert result.captured == [1] and result.skipped == [0]
    assert read_quad_burst(out).frames == 2


def test_other_plan_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "qb"
    capture_quad_burst(FakeQuad(), POSITIONS[:2], out, start_mm=0.0)
    with pytest.raises(InputFormatError, match="another plan or start position"):
        capture_quad_burst(FakeQuad(), POSITIONS[:2], out, start_mm=5.0)
