"""The burst format's one owner: Manifest/FrameEntry round trips, the capture handle, scales."""

from __future__ import annotations

import io
import json
import os
import signal
import threading
import time

import numpy as np
import pytest
import tifffile

from elphel_host.burst.capture import BurstRunner, capture_burst
from elphel_host.burst.io import read_burst
from elphel_host.burst.manifest import FrameEntry, Manifest, read_manifest
from elphel_host.burst.plan import BurstPlan, plan_burst, read_plan, write_plan
from elphel_host.errors import CaptureTimeout, InputFormatError, ScaleError
from elphel_host.fileio import partial_path
from elphel_host.mfsr.scale import MAX_SCALE, check_scale
from elphel_host.progress import ProgressLine
from elphel_host.stage.positioning import MoveResult

POSITIONS = [0.0, 0.01, 0.02, 0.03]


class Engine:
    """Frames of 4x6 px, each move optionally slow or gated by an event."""

    def __init__(self, *, delay_s: float = 0.0, gate: threading.Event | None = None) -> None:
        self.delay_s, self.gate, self.moves, self.stopped, self.frame = delay_s, gate, [], 0, 0

    def move(self, position_mm: float) -> MoveResult:
        if self.gate is not None:
            self.gate.wait(10)
        time.sleep(self.delay_s)
        self.moves.append(position_mm)
        return MoveResult(position_mm, round(position_mm, 3), 0, 1, position_mm)

    def acquire(self) -> tuple[bytes, dict]:
        self.frame += 1
        buf = io.BytesIO()
        tifffile.imwrite(buf, np.full((4, 6), self.frame, np.uint16))
        return buf.getvalue(), {"frame": self.frame, "timestamp_ns": self.frame, "bayer": None}

    def stop(self) -> None:
        self.stopped += 1
        if self.gate is not None:  # as on the rig: a stop ends the move in progress
            self.gate.set()


def test_a_captured_manifest_round_trips_key_for_key(tmp_path):
    top = {
        "plan": {"scale": 2},
        "optics": {"focal_length_mm": 35.0, "pixel_pitch_um": 2.2, "object_distance_mm": 500.0},
        "stage": {"mm_per_step": 0.01},
    }
    capture_burst(Engine(), POSITIONS, tmp_path, start_mm=5.0, top=top)
    raw = json.loads((tmp_path / "manifest.json").read_text())
    assert raw["frames"][1] == {
        "file": "frames/0001.tif",
        "index": 1,
        "stage_mm": 5.01,
        "caliper_mm": 5.01,
        "frame": 2,
        "timestamp_ns": 2,
    }
    assert raw["capture"] == {"start_mm": 5.0, "positions_mm": POSITIONS}
    assert raw["bayer"] is None and raw["plan"] == {"scale": 2} and raw["version"] == 1
    manifest = read_manifest(tmp_path)
    assert manifest is not None and manifest.to_json() == raw
    assert Manifest.from_json(raw) == manifest
    assert read_burst(tmp_path).manifest == manifest


def test_unknown_keys_are_kept_and_bad_fields_named():
    entry = FrameEntry.from_json({"file": "frames/0000.tif", "exposure_us": 5})
    assert entry.to_json() == {"file": "frames/0000.tif", "exposure_us": 5}
    with pytest.raises(ValueError, match=r"frames\[2\]\.index='x'; allowed: an integer"):
        FrameEntry.from_json({"file": "a.tif", "index": "x"}, where="frames[2]")
    with pytest.raises(ValueError, match="bayer='XYZW'; allowed: null or one of"):
        Manifest(bayer="XYZW")


def test_handle_reports_progress_waits_and_calls_back(tmp_path):
    gate = threading.Event()
    runner = BurstRunner(Engine(gate=gate), POSITIONS, tmp_path, start_mm=0.0)
    status = runner.start()
    ended: list[bool] = []
    status.add_callback(lambda s: ended.append(s.done))
    assert not status.done and status.progress.total == 4
    with pytest.raises(CaptureTimeout, match=r"not finished within 0\.1 s"):
        status.wait(0.1)
    gate.set()
    result = status.wait(10)
    assert result.captured == [0, 1, 2, 3] and not result.cancelled
    assert status.done and ended == [True]
    assert status.progress.state == "finished" and status.progress.done == 4
    late: list[bool] = []
    status.add_callback(lambda s: late.append(True))
    assert late == [True]


def test_cancel_stops_the_hardware_keeps_frames_and_resumes(tmp_path):
    engine = Engine(delay_s=0.05)
    stored: list[int] = []

    def on_frame(directory, manifest, index):
        stored.append(index)
        if index == 1:
            status.cancel()

    status = BurstRunner(engine, POSITIONS, tmp_path, start_mm=0.0, on_frame=on_frame).start()
    result = status.wait(10)
    assert result.cancelled and result.captured == [0, 1] and engine.stopped == 1
    assert status.progress.state == "cancelled"
    assert len(read_burst(tmp_path).infos) == 2
    again = capture_burst(Engine(), POSITIONS, tmp_path, start_mm=0.0)
    assert again.skipped == [0, 1] and again.captured == [2, 3]


def test_an_error_in_the_engine_stops_it_and_reaches_wait(tmp_path):
    class Broken(Engine):
        def acquire(self):
            raise OSError("camera gone")

    engine = Broken()
    status = BurstRunner(engine, POSITIONS, tmp_path, start_mm=0.0).start()
    with pytest.raises(OSError, match="camera gone"):
        status.wait(10)
    assert engine.stopped == 1 and status.progress.state == "failed"


def test_bad_top_fields_fail_before_the_first_move(tmp_path):
    engine = Engine()
    with pytest.raises(InputFormatError, match=r"optics\.speed=1; allowed: keys"):
        capture_burst(engine, POSITIONS, tmp_path, start_mm=0.0, top={"optics": {"speed": 1}})
    assert engine.moves == []


def test_one_scale_check_with_its_bounds_in_the_message():
    assert check_scale(np.int64(3)) == 3
    for bad in (0, MAX_SCALE + 1, True, 2.0, "2"):
        with pytest.raises(ScaleError, match=f"allowed: an integer 1..{MAX_SCALE}"):
            check_scale(bad)
    with pytest.raises(ScaleError, match=r"scale=1; allowed: an integer 2\.\.8"):
        plan_burst(scale=1, focal_length_mm=35, pixel_pitch_um=2.2, distance_mm=500)
    assert check_scale(16, maximum=None) == 16
    with pytest.raises(ScaleError, match="allowed: an integer >= 1"):
        check_scale(0, maximum=None)


def test_plan_file_round_trips_and_a_positions_only_plan_reads(tmp_path):
    plan = plan_burst(scale=2, focal_length_mm=35, pixel_pitch_um=2.2, distance_mm=500)
    path = write_plan(tmp_path / "plan.json", plan)
    assert json.loads(path.read_text()) == plan.to_json()
    assert read_plan(path) == plan
    (tmp_path / "mini.json").write_text(json.dumps({"positions_mm": [0, 0.5]}))
    assert read_plan(tmp_path / "mini.json") == BurstPlan(positions_mm=[0.0, 0.5])
    (tmp_path / "bad.json").write_text(json.dumps({"positions_mm": "x"}))
    with pytest.raises(InputFormatError, match=r"not a burst plan .*positions_mm='x'"):
        read_plan(tmp_path / "bad.json")


def test_progress_line_updates_in_place_on_a_terminal_only():
    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    tty, pipe = Tty(), io.StringIO()
    for stream in (tty, pipe):
        line = ProgressLine(stream)
        line.update("burst: 1/2")
        line.update("burst: 2/2")
        line.say("fusion: ")("done")
    assert pipe.getvalue() == "burst: 1/2\nburst: 2/2\nfusion: done\n"
    assert tty.getvalue() == "\rburst: 1/2\x1b[K\rburst: 2/2\x1b[K\nfusion: done\n"


def test_partial_names_keep_the_suffix_when_asked(tmp_path):
    assert partial_path(tmp_path / "a.tif").name == ".a.tif.part"
    assert partial_path(tmp_path / "a.tif", keep_suffix=True).name == ".a.part.tif"


def test_ctrl_c_in_wait_stops_the_hardware_before_it_goes_on(tmp_path):
    # Python's own SIGINT handler, installed again: a library an earlier test in this
    # process used may have replaced it below Python (signal.getsignal does not show
    # that), and then the Ctrl-C never reaches the wait
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    gate = threading.Event()
    engine = Engine(gate=gate)
    status = BurstRunner(engine, POSITIONS, tmp_path, start_mm=0.0).start()
    # Ctrl-C in a shell sends SIGINT to the process (any thread that does not block it
    # takes it), not to one thread as raise_signal from the timer's thread would
    timer = threading.Timer(0.2, os.kill, args=(os.getpid(), signal.SIGINT))
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            status.wait(10)
        assert engine.stopped == 1  # stopped while the move was still in progress
    finally:
        gate.set()
        timer.cancel()
        signal.signal(signal.SIGINT, previous)
    result = status.wait(10)
    assert result.cancelled and engine.stopped == 1
