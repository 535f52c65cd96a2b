"""The demo's progress: its commands' own progress relayed to one line on stderr.

`make demo` runs `elphel ... --json` commands; while one runs, what it writes on stderr
(its progress) is shown on the demo's progress line: a bar over the demo's commands with
the rate and the time left on a terminal, plain lines otherwise. stdout keeps the
demo's account (``[demo] ...``) and nothing else.
"""

from __future__ import annotations

import ast
import io
import re
from pathlib import Path

import pytest

from elphel_host.progress import ProgressLine
from elphel_sim.demo import burst as demo_burst
from elphel_sim.demo import calib as demo_calib
from elphel_sim.demo import depth as demo_depth
from elphel_sim.demo import rig as demo_rig
from elphel_sim.demo import run as demo
from elphel_sim.demo.rig import DemoError, DemoProgress, elphel, step
from tests.host.jp4.test_convert import record

ANSI = re.compile(r"\x1b\[[0-9;]*m")


class Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def use(monkeypatch: pytest.MonkeyPatch, stream: io.StringIO, total: int) -> DemoProgress:
    progress = DemoProgress(ProgressLine(stream), total=total)
    monkeypatch.setattr(demo_rig, "DEMO_PROGRESS", progress)
    return progress


def convert(tmp_path: Path, out: str = "o") -> dict:
    """`elphel jp4 convert` of six frames: a command that shows its progress."""
    record(tmp_path / "rec", 3, (0, 1))
    return elphel("jp4", "convert", str(tmp_path / "rec"), "--out", str(tmp_path / out))


def test_a_pipe_gets_the_commands_progress_as_plain_lines(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    pipe = io.StringIO()
    progress = use(monkeypatch, pipe, total=4)
    progress.done = 1
    progress.line.restart(1)  # the rate counts from here: none until the next command
    result = convert(tmp_path)
    assert result["layout"] == "files"  # the command's JSON, parsed
    lines = pipe.getvalue().splitlines()
    assert lines[0].startswith("demo: 1/4 commands · elphel jp4 convert: converting 1/6")
    assert re.match(r"demo: 1/4 commands .*· elphel jp4 convert: converting 6/6", lines[-1])
    assert "left)" in lines[-1]  # the command's own rate and time left
    assert "\r" not in pipe.getvalue() and "━" not in pipe.getvalue()
    assert progress.done == 2
    step("next")
    assert capsys.readouterr().out == "[demo] next\n"  # the account alone on stdout


def test_a_terminal_gets_one_updating_line_with_a_bar_ended_by_the_account(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    tty = Tty()
    use(monkeypatch, tty, total=2)
    convert(tmp_path, "one")
    convert(tmp_path, "two")  # in the second the demo's own rate and time left appear
    step("converted")
    updates = [ANSI.sub("", u) for u in tty.getvalue().split("\x1b[K")[:-1]]
    assert all(u.startswith("\r") for u in updates) and len(updates) >= 12
    assert updates[0].startswith("\r" + "━" * 24 + " demo: 0/2 commands · elphel jp4 convert")
    last = updates[-1]
    # the demo's count with its rate and time left, then the command's own
    assert re.search(r"demo: 1/2 commands \(\S+/s, \d+:\d\d left\) · elphel jp4 convert: ", last)
    assert last.endswith(" left)") and last.count(" left)") == 2, last
    assert tty.getvalue().endswith("\x1b[K\n")  # the line is ended before the account
    assert capsys.readouterr().out == "[demo] converted\n"


def test_a_failed_command_is_a_demo_error_with_its_message(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    use(monkeypatch, io.StringIO(), total=1)
    with pytest.raises(DemoError) as failed:
        elphel("mfsr", str(tmp_path), "--scale", "2", "--out", str(tmp_path / "x.tif"))
    message = str(failed.value)
    assert message.startswith(f"elphel mfsr {tmp_path}") and "elphel: " in message


def commands_run(node: ast.AST, times: int = 1, *, module: object = None) -> int:
    """`elphel(...)` calls under ``node``, a call in a loop over a literal counted per turn.

    ``range(NAME)`` counts as a literal when NAME is an int constant of ``module``.
    """
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "elphel":
        return times + sum(
            commands_run(c, times, module=module) for c in ast.iter_child_nodes(node)
        )
    if isinstance(node, ast.For):
        it = node.iter
        if isinstance(it, (ast.Tuple, ast.List)):
            turns = len(it.elts)
        elif isinstance(it, ast.Call) and getattr(it.func, "id", "") == "range":
            (arg,) = it.args
            if isinstance(arg, ast.Name):
                count = getattr(module, arg.id)
            else:
                assert isinstance(arg, ast.Constant), (
                    "a loop over range(N), N a literal or constant"
                )
                count = arg.value
            assert isinstance(count, int), f"line {node.lineno}: range() of {count!r}"
            turns = count
        else:
            inner = sum(commands_run(c, module=module) for c in node.body)
            assert inner == 0, f"line {node.lineno}: elphel() in a loop of unknown length"
            turns = 0
        return sum(commands_run(c, times * turns, module=module) for c in node.body)
    return sum(commands_run(c, times, module=module) for c in ast.iter_child_nodes(node))


def counted(module: object) -> int:
    return commands_run(ast.parse(Path(module.__file__).read_text()), module=module)  # type: ignore[attr-defined]


def test_the_bar_counts_every_command_of_the_demo() -> None:
    own, burst, calib, depth = (counted(m) for m in (demo, demo_burst, demo_calib, demo_depth))
    assert depth == demo_depth.COMMANDS == 11
    assert burst == demo_burst.COMMANDS == 9
    assert calib == demo_calib.COMMANDS == 4 + demo_calib.VIEWS + 1 + 3
    assert own + burst + calib + depth == demo.COMMANDS
