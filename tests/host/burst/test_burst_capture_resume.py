"""Burst capture survives Ctrl-C and kill -9: re-running completes it, each frame once."""

import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from elphel_host.burst.capture import capture_burst
from elphel_host.burst.io import read_burst
from elphel_host.stage.positioning import MoveResult

POSITIONS = [0.0, 0.011, 0.022, 0.033, 0.044, 0.055, 0.066, 0.077]

FAKE = textwrap.dedent(
    """
    import io, sys, time
    import numpy as np, tifffile
    from elphel_host.stage.positioning import MoveResult

    class FakeEngine:
        def __init__(self, delay_s=0.0, fail_at=None):
            self.delay_s, self.fail_at, self.moves, self.stopped = delay_s, fail_at, [], 0
            self.frame = int(time.time() * 1000) * 100  # unique across runs

        def move(self, position_mm):
            if self.fail_at is not None and len(self.moves) == self.fail_at:
                raise KeyboardInterrupt
            self.moves.append(position_mm)
            time.sleep(self.delay_s)
            return MoveResult(position_mm, round(position_mm, 2), 0, 1, position_mm)

        def acquire(self):
            self.frame += 1
            image = np.full((4, 6), self.frame % 65536, dtype=np.uint16)
            buf = io.BytesIO()
            tifffile.imwrite(buf, image, metadata={"frame": self.frame})
            return buf.getvalue(), {"frame": self.frame, "timestamp_ns": self.frame * 1000,
                                    "bayer": "GRBG"}

        def stop(self):
            self.stopped += 1
    """
)
exec(FAKE)  # defines FakeEngine here too


def test_ctrl_c_stops_stage_and_leaves_a_valid_partial_burst(tmp_path):
    engine = FakeEngine(fail_at=3)  # noqa: F821
    with pytest.raises(KeyboardInterrupt):
        capture_burst(engine, POSITIONS, tmp_path, start_mm=10.0)
    assert engine.stopped == 1
    burst = read_burst(tmp_path)
    assert len(burst.infos) == 3
    assert [i.stage_mm for i in burst.infos] == pytest.approx([10.0, 10.011, 10.022])
    again = FakeEngine()  # noqa: F821
    result = capture_burst(again, POSITIONS, tmp_path, start_mm=10.0)
    assert result.skipped == [0, 1, 2] and result.captured == [3, 4, 5, 6, 7]
    assert again.moves == pytest.approx([10.0 + p for p in POSITIONS[3:]])
    burst = read_burst(tmp_path)
    assert [i.file for i in burst.infos] == [f"frames/{i:04d}.tif" for i in range(8)]


def test_other_plan_in_the_same_directory_is_refused(tmp_path):
    capture_burst(FakeEngine(), POSITIONS[:2], tmp_path, start_mm=10.0)  # noqa: F821
    with pytest.raises(ValueError, match="another plan"):
        capture_burst(FakeEngine(), POSITIONS, tmp_path, start_mm=10.0)  # noqa: F821


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_kill_9_at_a_random_moment_then_rerun_completes_each_frame_once(tmp_path, seed):
    script = tmp_path / "run.py"
    out = tmp_path / "burst"
    script.write_text(
        FAKE
        + textwrap.dedent(
            f"""
            from elphel_host.burst.capture import capture_burst
            capture_burst(FakeEngine(delay_s=0.2), {POSITIONS!r}, {str(out)!r}, start_mm=10.0)
            print("done")
            """
        )
    )
    rng = np.random.default_rng(seed)
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    time.sleep(1.2 + rng.uniform(0, 0.8))  # imports, then somewhere within the burst
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    proc.stdout.close()
    if (out / "manifest.json").exists():
        json.loads((out / "manifest.json").read_text())  # never half-written
    rerun = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=60
    )
    assert rerun.returncode == 0, rerun.stderr
    burst = read_burst(out)
    files = [i.file for i in burst.infos]
    assert files == [f"frames/{i:04d}.tif" for i in range(len(POSITIONS))]
    assert len({i.frame for i in burst.infos}) == len(POSITIONS)
    assert not list((out / "frames").glob("*.part"))


def test_move_result_type_is_what_the_runner_records():
    r = MoveResult(1.0, 1.01, 5, 1, 1.005)
    assert r.caliper_mm == 1.01
