"""ProgressLine (elphel_host.progress): bar, rate and time left on a terminal; plain lines else."""

from __future__ import annotations

import io
import json
import re
import time
from pathlib import Path

import pytest

from elphel_host.cli import main
from elphel_host.progress import ProgressLine, format_rate
from tests.host.jp4.test_convert import record

ANSI = re.compile(r"\x1b\[[0-9;]*m")
REMAINING_STYLE = "\x1b[90m"  # rich's bar.back colour


def strip_ansi(text: str) -> str:
    return ANSI.sub("", text)


class Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_terminal_gets_a_bar_with_rate_and_time_left() -> None:
    tty, clock = Tty(), Clock()
    line = ProgressLine(tty, clock=clock)
    line.update("burst: 0/10", done=0, total=10)
    clock.t += 4.0
    line.update("burst: 2/10", done=2, total=10)  # 0.5/s, 8 left: 16 s
    line.end()
    first, second = tty.getvalue().split("\x1b[K")[:2]
    # rich draws the bar: 24 cells, the done part in one colour, the rest in another.
    assert strip_ansi(first) == "\r" + "━" * 24 + " burst: 0/10"
    assert strip_ansi(second) == "\r━━━━╸" + "━" * 19 + " burst: 2/10 (0.5/s, 0:16 left)"
    done_part, _rest = second.split(REMAINING_STYLE, 1)
    assert strip_ansi(done_part) == "\r━━━━╸"  # 2/10 of 24 cells: 4.8
    assert first.startswith("\r" + REMAINING_STYLE)  # nothing done yet
    assert tty.getvalue().endswith("\n")


def test_a_pipe_gets_plain_lines_with_rate_and_time_left() -> None:
    pipe, clock = io.StringIO(), Clock()
    line = ProgressLine(pipe, clock=clock)
    line.update("converting 1/100: a", done=1, total=100)
    clock.t += 2.0
    line.update("converting 5/100: b", done=5, total=100)  # 2.5/s since the start: 38 s
    line.end()
    assert pipe.getvalue() == "converting 1/100: a\nconverting 5/100: b (2.5/s, 0:38 left)\n"
    assert "\r" not in pipe.getvalue() and "#" not in pipe.getvalue()


def test_the_rate_counts_from_the_start_of_the_work() -> None:
    # two quads done 8.7 s and 8.8 s after the start were once reported as 9.07/s
    pipe, clock = io.StringIO(), Clock()
    line = ProgressLine(pipe, clock=clock)
    clock.t += 8.7
    line.update("1/2 quads", done=1, total=2)
    clock.t += 0.1
    line.update("2/2 quads", done=2, total=2)
    assert pipe.getvalue().splitlines() == [
        "1/2 quads (0.11/s, 0:09 left)",
        "2/2 quads (0.23/s, 0:00 left)",
    ]
    # resumed work: the rate counts what was done since the restart only
    line.restart(2)
    clock.t += 1.0
    line.update("3/4 quads", done=3, total=4)
    assert pipe.getvalue().splitlines()[-1] == "3/4 quads (1/s, 0:01 left)"


def test_rates_read_like_numbers_with_their_unit() -> None:
    assert format_rate(1470.4) == "1,470/s" and format_rate(36512.0) == "36,512/s"
    assert format_rate(14.66) == "14.7/s" and format_rate(9.074) == "9.07/s"
    assert format_rate(0.5) == "0.5/s" and format_rate(2.0) == "2/s"
    assert format_rate(0.0042) == "0.0042/s"
    assert format_rate(0.417, "mm") == "0.42 mm/s"
    pipe, clock = io.StringIO(), Clock()
    line = ProgressLine(pipe, clock=clock)
    clock.t += 2.0
    line.update("stage: 1.2 of 4.8 mm", done=1.2, total=4.8, unit="mm")
    assert pipe.getvalue() == "stage: 1.2 of 4.8 mm (0.6 mm/s, 0:06 left)\n"


def test_a_silent_step_ticks_on_a_terminal_and_says_itself_once_on_a_pipe() -> None:
    tty = Tty()
    line = ProgressLine(tty)
    with line.ticking("mfsr: fusing b (robust x2)", every_s=0.01):
        time.sleep(0.2)
    line.end()
    shown = tty.getvalue().split("\x1b[K")
    assert shown[0] == "\rmfsr: fusing b (robust x2)"
    assert re.fullmatch(r"\rmfsr: fusing b \(robust x2\) \(0 s\)", shown[1]), shown[1]
    pipe = io.StringIO()
    line = ProgressLine(pipe)
    with line.ticking("mfsr compare: 1/3 bicubic x2", every_s=0.01):
        time.sleep(0.05)
    assert pipe.getvalue() == "mfsr compare: 1/3 bicubic x2\n"


def test_hours_in_the_time_left() -> None:
    pipe, clock = io.StringIO(), Clock()
    line = ProgressLine(pipe, clock=clock)
    line.update("x", done=0, total=3601)
    clock.t += 1.0
    line.update("x", done=1, total=3601)
    assert pipe.getvalue().splitlines()[-1] == "x (1/s, 1:00:00 left)"


def test_json_keeps_stdout_to_the_one_object(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    record(tmp_path / "rec", 3, (0, 1))
    args = ["jp4", "convert", str(tmp_path / "rec"), "--out", str(tmp_path / "o"), "--json"]
    assert main(args) == 0
    out, err = capsys.readouterr()
    assert len(out.splitlines()) == 1 and json.loads(out)["layout"] == "files"
    assert "converting 6/6" in err and "left)" in err  # progress with its rate, on stderr


def test_stage_calibrate_reports_each_run_on_stderr(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from elphel_sim.stage_server import SimStage

    with SimStage(seed=3, time_scale=100) as sim:
        sim.wait_booted()
        monkeypatch.setenv("ELPHEL_STAGE_URL", sim.tcp_url)
        model = str(tmp_path / "model.json")
        argv = ["stage", "calibrate", "--model", model, "--span-mm", "20", "--repeats", "2"]
        assert main([*argv, "--json"]) == 0
    out, err = capsys.readouterr()
    assert len(out.splitlines()) == 1 and "mm_per_step" in json.loads(out)
    runs = [line for line in err.splitlines() if line.startswith("calibrate: run ")]
    assert [r.split(":")[1] for r in runs] == [" run 1/2", " run 2/2"], err
    assert runs[-1].endswith("left)"), err  # the rate and the time left, as a bar has


def test_stage_move_shows_the_caliper_on_the_way(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from elphel_host.stage.model import StageModel
    from elphel_sim.stage_server import SimStage

    with SimStage(seed=4, time_scale=100) as sim:
        sim.wait_booted()
        monkeypatch.setenv("ELPHEL_STAGE_URL", sim.tcp_url)
        assert main(["stage", "home", "--json"]) == 0
        capsys.readouterr()
        model = tmp_path / "model.json"
        StageModel().save(model)  # the nominal mm/step
        assert main(["stage", "move", "12.5", "--model", str(model), "--json"]) == 0
    out, err = capsys.readouterr()
    assert len(out.splitlines()) == 1 and json.loads(out)["target_mm"] == 12.5
    lines = [line for line in err.splitlines() if line.startswith("stage: caliper ")]
    assert len(lines) >= 3, err  # one line per reading: not a terminal, so no bar
    assert all(line.count("target 12.500 mm") == 1 for line in lines)
    assert "left)" in lines[-1] and "\r" not in err and "━" not in err
