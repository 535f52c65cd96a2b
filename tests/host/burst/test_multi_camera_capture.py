"""`capture_multi_burst`: one burst directory per camera, the same positions, resumable."""

from __future__ import annotations

import io
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import tifffile

from elphel_host.burst.io import read_burst
from elphel_host.burst.multi_capture import MultiCameraEngine, capture_multi_burst
from elphel_host.cli import main as cli_main
from elphel_host.errors import InputFormatError
from elphel_host.stage.positioning import MoveResult

POSITIONS = [0.0, 0.25, 0.5, 0.75]


class FakeCamera:
    """A camera whose frames say where the carriage was; counts who waits with whom."""

    def __init__(self, index: int, rig: FakeRig) -> None:
        self.index, self.rig, self.frame = index, rig, 0

    def capture(self, port: int) -> Any:
        self.rig.barrier.wait(timeout=5)  # both cameras are asked at the same moment
        self.frame += 1
        buf = io.BytesIO()
        value = 100 * self.index + int(self.rig.at * 100)
        tifffile.imwrite(buf, np.full((4, 6), value, np.uint16))
        meta = {"frame": self.frame, "timestamp_ns": 10 * self.frame, "bayer": "BGGR"}
        return type("Got", (), {"tiff": buf.getvalue(), "metadata": meta})()


class FakeRig:
    def __init__(self, cameras: int = 2, fail_at: int | None = None) -> None:
        self.barrier = threading.Barrier(cameras)
        self.at, self.moves, self.stopped, self.fail_at = 0.0, [], 0, fail_at
        self.cameras = [FakeCamera(i, self) for i in range(cameras)]

    def move(self, position_mm: float) -> MoveResult:
        if self.fail_at is not None and len(self.moves) == self.fail_at:
            raise KeyboardInterrupt
        self.moves.append(position_mm)
        self.at = position_mm
        return MoveResult(position_mm, round(position_mm, 3), 0, 1, position_mm)

    def acquire_all(self) -> list[tuple[bytes, dict[str, Any]]]:
        engine = MultiCameraEngine(positioner=None, cameras=self.cameras, settle_s=0)  # type: ignore[arg-type]
        return engine.acquire_all()

    def stop(self) -> None:
        self.stopped += 1


def test_one_burst_per_camera_at_the_same_positions(tmp_path: Path) -> None:
    rig = FakeRig()
    result = capture_multi_burst(rig, POSITIONS, tmp_path / "b", start_mm=10.0)
    assert result.captured == [0, 1, 2, 3]
    for cam in (0, 1):
        burst = read_burst(tmp_path / "b" / f"cam{cam}")
        m = burst.manifest
        assert [e.stage_mm for e in m.frames] == [10.0 + p for p in POSITIONS]
        assert m.bayer == "BGGR" and m.extra["rig_camera"] == cam
        values = [int(f[0, 0]) for f in burst.frames]
        assert values == [100 * cam + int((10.0 + p) * 100) for p in POSITIONS]


def test_interrupted_then_resumed_takes_only_the_missing_positions(tmp_path: Path) -> None:
    first = FakeRig(fail_at=2)
    with pytest.raises(KeyboardInterrupt):
        capture_multi_burst(first, POSITIONS, tmp_path / "b", start_mm=0.0)
    assert first.stopped == 1
    second = FakeRig()
    result = capture_multi_burst(second, POSITIONS, tmp_path / "b", start_mm=0.0)
    assert (result.skipped, result.captured) == ([0, 1], [2, 3])
    assert second.moves == POSITIONS[2:]
    for cam in (0, 1):
        assert len(read_burst(tmp_path / "b" / f"cam{cam}").manifest.frames) == 4


def test_a_burst_of_another_plan_is_refused(tmp_path: Path) -> None:
    capture_multi_burst(FakeRig(), POSITIONS, tmp_path / "b", start_mm=0.0)
    with pytest.raises(InputFormatError, match="another plan"):
        capture_multi_burst(FakeRig(), POSITIONS, tmp_path / "b", start_mm=1.0)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--token", "a", "--token", "b", "--token", "c"], "3 --token for 2 --camera"),
        (["--fuse"], "--fuse: with one --camera only"),
        (["--quad"], "--quad: a quad camera is one --camera"),
    ],
)
def test_several_cameras_usage_errors_name_the_option(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], message: str
) -> None:
    plan = tmp_path / "plan.json"
    plan.write_text('{"positions_mm": [0.0, 0.5]}')
    argv = ["burst", "capture", "--camera", "http://127.0.0.1:1", "--camera", "http://127.0.0.1:2"]
    argv += ["--stage", "socket://127.0.0.1:1", "--plan", str(plan), "--out", str(tmp_path / "o")]
    with pytest.raises(SystemExit) as info:
        cli_main([*argv, *extra])
    assert info.value.code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()  # refused before anything is touched
