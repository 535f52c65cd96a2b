"""`burst capture --fuse`: fusion fed while capturing equals `elphel mfsr` on the result.

The engine renders real frames of a textured scene at the sub-pixel shifts its stage
positions produce (the optics in the manifest predict them, as on the rig), so the
registration, its stage prior and the reconstruction all run for real.
"""

from __future__ import annotations

import io
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

from elphel_host.burst.capture import capture_burst
from elphel_host.burst.io import read_burst
from elphel_host.cli import main
from elphel_host.errors import FusionError
from elphel_host.mfsr.stream import FusionStream, finish_and_write
from elphel_host.mfsr.synth import make_burst
from elphel_host.stage.positioning import MoveResult

SCALE = 2
N = 8
START_MM = 40.0
OPTICS = {"focal_length_mm": 35.0, "pixel_pitch_um": 2.2, "object_distance_mm": 500.0}
PX_PER_MM = 35.0 / (500.0 - 35.0) * 1000.0 / 2.2
TILT_DEG = math.degrees(math.atan(1 / SCALE))
# frame i at x = i*S/N px along the tilted axis (the plan's geometry), converted to mm
POSITIONS = [i * SCALE / N / math.cos(math.radians(TILT_DEG)) / PX_PER_MM for i in range(N)]
TOP = {"optics": OPTICS, "stage": {"mm_per_step": 0.008778, "axis_angle_deg": TILT_DEG}}


def _scene(h: int, w: int) -> np.ndarray:
    rng = np.random.default_rng(7)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    img = 0.5 + 0.25 * np.sin(xx * 0.21 + yy * 0.05) * np.cos(yy * 0.13)
    img += (((xx // 24 + yy // 24) % 2) * 0.2 - 0.1).astype(np.float32)
    img += 0.15 * cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), 1.2)
    return np.clip(img, 0, 1).astype(np.float32)


def _true_shift(rel_mm: float) -> tuple[float, float]:
    px = rel_mm * PX_PER_MM
    t = math.radians(TILT_DEG)
    return (px * math.sin(t), px * math.cos(t))


class SceneEngine:
    """Frames of one scene at the shift each stage position gives; optional faults."""

    def __init__(
        self,
        *,
        shape: tuple[int, int] = (96, 128),
        bayer: str | None = None,
        outlier: int | None = None,
        bad_dtype: int | None = None,
        interrupt_at: int | None = None,
        settle=None,
    ) -> None:
        self.shape, self.bayer = shape, bayer
        self.outlier, self.bad_dtype, self.interrupt_at = outlier, bad_dtype, interrupt_at
        self.hr = _scene(shape[0] * SCALE, shape[1] * SCALE)
        self.target = START_MM
        self.moves: list[float] = []
        self.stopped = 0
        self.frame = 1000
        self.settle = settle  # called before each move: the time the carriage takes

    def move(self, position_mm: float) -> MoveResult:
        if self.interrupt_at is not None and len(self.moves) == self.interrupt_at:
            raise KeyboardInterrupt
        if self.settle is not None:
            self.settle(len(self.moves))
        self.moves.append(position_mm)
        self.target = position_mm
        # the caliper reads a few µm off, as on the rig: the prior is close, not exact
        caliper = round(position_mm + 0.003 * math.sin(7 * position_mm), 4)
        return MoveResult(position_mm, caliper, 0, 1, position_mm)

    def acquire(self) -> tuple[bytes, dict]:
        index = int(np.argmin([abs(START_MM + p - self.target) for p in POSITIONS]))
        self.frame += 1
        if index == self.outlier:  # a different scene: a glare, a person walking through
            lr = np.random.default_rng(index).uniform(0, 1, self.shape).astype(np.float32)
        else:
            (lr,) = make_burst(
                self.hr,
                [_true_shift(POSITIONS[index])],
                scale=SCALE,
                noise_sigma=0.004,
                seed=self.frame,
            )
        dn = np.clip(np.rint(lr * 3000 + 200), 0, 65535)
        image = dn.astype(np.uint8 if index == self.bad_dtype else np.uint16)
        buf = io.BytesIO()
        tifffile.imwrite(buf, image, metadata={"frame": self.frame})
        meta = {"frame": self.frame, "timestamp_ns": self.frame * 1000, "bayer": self.bayer}
        return buf.getvalue(), meta

    def stop(self) -> None:
        self.stopped += 1


def _capture(engine, out, stream, *, fed=None, progress=None):
    def on_frame(directory, manifest, index):
        if fed is not None:
            fed.append(index)
        stream.frame_stored(directory, manifest, index)

    return capture_burst(
        engine, POSITIONS, out, start_mm=START_MM, top=TOP, on_frame=on_frame, progress=progress
    )


def _run_mfsr(tmp_path, burst_dir, method="robust"):
    """`elphel mfsr BURST_DIR --scale S --method M --json` on the finished burst."""
    post = tmp_path / "post.tif"
    args = ["mfsr", str(burst_dir), "--scale", str(SCALE), "--method", method]
    assert main([*args, "--out", str(post), "--json"]) == 0
    return post


@pytest.mark.parametrize(
    ("bayer", "method"), [(None, "robust"), ("GRBG", "robust"), (None, "baseline")]
)
def test_streamed_fusion_equals_elphel_mfsr_on_the_finished_burst(tmp_path, capsys, bayer, method):
    out = tmp_path / "burst"
    shape = (128, 160) if bayer else (96, 128)
    statuses = []
    with FusionStream(frames=N, scale=SCALE, method=method) as stream:
        _capture(
            SceneEngine(shape=shape, bayer=bayer),
            out,
            stream,
            progress=lambda d, t, m: statuses.append(stream.status()),
        )
        fused = finish_and_write(stream, out / "fused.tif", burst=out)
    assert statuses[-1].startswith("registered ")
    assert fused["registered_before_finish"] >= 1 and fused["after_capture_s"] > 0
    capsys.readouterr()
    post = _run_mfsr(tmp_path, out, method)
    mfsr = json.loads(capsys.readouterr().out)
    # bit for bit: the same registration, the same reconstruction, the same file
    np.testing.assert_array_equal(tifffile.imread(out / "fused.tif"), tifffile.imread(post))
    assert fused["registration"] == mfsr["registration"]
    assert fused["excluded"] == mfsr["excluded"] == []
    same = {k: v for k, v in mfsr.items() if k not in ("seconds", "peak_memory_mb", "out")}
    del same["preview"]
    assert {k: fused[k] for k in same} == same
    assert (out / "fused.png").is_file()
    # and it is a sound fusion, not just an equal one: the shifts are the true ones
    for r, p in zip(fused["registration"], POSITIONS, strict=True):
        assert r["shift"] == pytest.approx(_true_shift(p), abs=0.05)


def test_excluded_frame_is_reported_and_left_out_as_in_elphel_mfsr(tmp_path, capsys):
    out = tmp_path / "burst"
    statuses = []

    def settle(stored):  # the stage takes long enough for the background to keep up
        deadline = time.monotonic() + 20
        while stream.registered < stored and time.monotonic() < deadline:
            time.sleep(0.01)

    with FusionStream(frames=N, scale=SCALE) as stream:
        _capture(
            SceneEngine(outlier=5, settle=settle),
            out,
            stream,
            progress=lambda d, t, m: statuses.append(stream.status()),
        )
        fused = finish_and_write(stream, out / "fused.tif", burst=out)
        assert "excluded [5]" in stream.status()
    assert fused["used"] == N - 1
    assert [e["index"] for e in fused["excluded"]] == [5]
    assert "correlation" in fused["excluded"][0]["reason"]
    # progress said so while capturing: after frame 6 was stored, frame 5 was registered
    assert "excluded" not in statuses[4]
    assert statuses[6].startswith("registered ") and statuses[6].endswith(", excluded [5]")
    capsys.readouterr()
    post = _run_mfsr(tmp_path, out)
    mfsr = json.loads(capsys.readouterr().out)
    assert fused["excluded"] == mfsr["excluded"]
    assert fused["registration"] == mfsr["registration"]
    np.testing.assert_array_equal(tifffile.imread(out / "fused.tif"), tifffile.imread(post))


def test_fusion_error_keeps_the_capture_going_and_writes_nothing(tmp_path):
    out = tmp_path / "burst"
    engine = SceneEngine(bad_dtype=3)  # a frame elphel mfsr would refuse too
    with FusionStream(frames=N, scale=SCALE) as stream:
        result = _capture(engine, out, stream)
        assert result.captured == list(range(N))  # every frame captured and kept
        with pytest.raises(FusionError, match=r"frames/0003\.tif.*dtype='uint8'; allowed: uint16"):
            finish_and_write(stream, out / "fused.tif", burst=out)
        assert stream.failed and "0003.tif" in stream.status()
    assert engine.stopped == 0 and len(engine.moves) == N
    manifest = json.loads((out / "manifest.json").read_text())
    assert [e["file"] for e in manifest["frames"]] == [f"frames/{i:04d}.tif" for i in range(N)]
    assert sorted(p.name for p in out.iterdir()) == ["frames", "manifest.json"]
    # and elphel mfsr refuses the same frame
    assert main(["mfsr", str(out), "--scale", "2", "--out", str(tmp_path / "x.tif")]) == 1


def test_unwritable_output_is_a_fusion_error_and_leaves_the_old_file(tmp_path):
    out = tmp_path / "burst"
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("a file where the output directory should be")
    with FusionStream(frames=N, scale=SCALE) as stream:
        _capture(SceneEngine(), out, stream)
        with pytest.raises(FusionError, match="cannot write"):
            finish_and_write(stream, blocker / "fused.tif", burst=out)
    assert blocker.read_text().startswith("a file")
    read_burst(out)


def test_ctrl_c_leaves_no_fused_file_and_the_resumed_capture_feeds_present_frames_first(
    tmp_path, capsys
):
    out = tmp_path / "burst"
    engine = SceneEngine(interrupt_at=3)
    with (
        pytest.raises(KeyboardInterrupt),
        FusionStream(frames=N, scale=SCALE) as stream,
    ):
        _capture(engine, out, stream)
    assert engine.stopped == 1
    assert not any(t.name == "mfsr-stream" and t.is_alive() for t in threading.enumerate())
    assert sorted(p.name for p in out.iterdir()) == ["frames", "manifest.json"]
    assert len(read_burst(out).infos) == 3
    # frame 0 lost too: the reference arrives after frames 1 and 2 were fed
    (out / "frames" / "0000.tif").unlink()
    fed: list[int] = []
    with FusionStream(frames=N, scale=SCALE) as stream:
        result = _capture(SceneEngine(), out, stream, fed=fed)
        fused = finish_and_write(stream, out / "fused.tif", burst=out)
    assert result.skipped == [1, 2] and result.captured == [0, 3, 4, 5, 6, 7]
    assert fed == [1, 2, 0, 3, 4, 5, 6, 7]
    capsys.readouterr()
    post = _run_mfsr(tmp_path, out)
    assert json.loads(capsys.readouterr().out)["registration"] == fused["registration"]
    np.testing.assert_array_equal(tifffile.imread(out / "fused.tif"), tifffile.imread(post))


def test_bad_options_name_the_value():
    with pytest.raises(ValueError, match="method='magic'"):
        FusionStream(frames=4, scale=2, method="magic")
    with pytest.raises(ValueError, match="scale=9"):
        FusionStream(frames=4, scale=9)


@pytest.mark.parametrize(
    ("extra", "plan", "message"),
    [
        (["--scale", "2"], {"scale": 2}, "--scale: allowed only with --fuse"),
        (["--fuse"], {}, "--fuse: scale=None from the plan"),
        (["--fuse", "--scale", "9"], {"scale": 2}, "--fuse: scale=9 from --scale"),
    ],
)
def test_fuse_options_are_checked_before_the_rig_is_touched(tmp_path, capsys, extra, plan, message):
    path = tmp_path / "plan.json"
    path.write_text(json.dumps({"positions_mm": POSITIONS, **plan}))
    rig = ["--camera", "http://127.0.0.1:9", "--stage", "socket://127.0.0.1:9"]
    argv = ["burst", "capture", *rig, "--plan", str(path), "--out", str(tmp_path / "b")]
    with pytest.raises(SystemExit) as exit_:
        main([*argv, *extra])
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "b").exists()


def test_kill_9_during_a_fused_capture_then_rerun_gives_the_posthoc_result(tmp_path):
    out = tmp_path / "burst"
    script = tmp_path / "run.py"
    script.write_text(
        "import sys, time\n"
        f"sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "import test_capture_fuse as t\n"
        "class Slow(t.SceneEngine):\n"
        "    def move(self, position_mm):\n"
        "        time.sleep(0.25)\n"
        "        return super().move(position_mm)\n"
        "with t.FusionStream(frames=t.N, scale=t.SCALE) as stream:\n"
        f"    t._capture(Slow(), {str(out)!r}, stream)\n"
        f"    t.finish_and_write(stream, {str(out / 'fused.tif')!r}, burst={str(out)!r})\n"
        "print('done')\n"
    )
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 30
    while not (out / "frames" / "0003.tif").exists() and time.monotonic() < deadline:
        time.sleep(0.02)  # imports done, a few frames in, the worker busy
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    proc.stdout.close()
    assert not (out / "fused.tif").exists()
    assert 3 <= len(read_burst(out).infos) < N
    rerun = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=60
    )
    assert rerun.returncode == 0, rerun.stderr
    names = sorted(p.name for p in out.iterdir())
    assert names == ["frames", "fused.png", "fused.tif", "manifest.json"]
    assert not list((out / "frames").glob("*.part"))
    post = _run_mfsr(tmp_path, out)
    np.testing.assert_array_equal(tifffile.imread(out / "fused.tif"), tifffile.imread(post))


def test_unwritable_fused_out_fails_before_the_rig_is_touched(tmp_path, capsys):
    path = tmp_path / "plan.json"
    path.write_text(json.dumps({"positions_mm": POSITIONS, "scale": 2}))
    (tmp_path / "file").write_text("not a directory")
    rig = ["--camera", "http://127.0.0.1:9", "--stage", "socket://127.0.0.1:9"]
    argv = ["burst", "capture", *rig, "--plan", str(path), "--out", str(tmp_path / "b")]
    assert main([*argv, "--fuse", "--fused-out", str(tmp_path / "file" / "x.tif")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("elphel: ") and "file" in err[0]
    assert not (tmp_path / "b").exists()
