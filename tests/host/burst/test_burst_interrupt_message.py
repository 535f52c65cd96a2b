"""Ctrl-C during `elphel burst capture` says what was kept and that the command resumes."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from elphel_host import cli
from elphel_host.burst.capture import capture_burst
from elphel_host.burst.cli import interrupted
from tests.host.burst.test_burst_capture_resume import POSITIONS, FakeEngine  # type: ignore[attr-defined]


def test_the_message_counts_the_frames_kept(tmp_path: Path) -> None:
    with pytest.raises(KeyboardInterrupt):
        capture_burst(FakeEngine(fail_at=3), POSITIONS, tmp_path / "b", start_mm=10.0)
    e = interrupted(tmp_path / "b", len(POSITIONS), "frames")
    assert str(e) == (f"3 of 8 frames kept in {tmp_path / 'b'}; the same command captures the rest")
    assert str(interrupted(tmp_path / "none", 8, "quad sets")).startswith("0 of 8 quad sets")


def test_main_prints_it(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    def capture(args: argparse.Namespace) -> int:
        raise KeyboardInterrupt("3 of 8 frames kept in b; the same command captures the rest")

    class Parser:
        def parse_args(self, argv: object) -> argparse.Namespace:
            return argparse.Namespace(func=capture)

    monkeypatch.setattr(cli, "build_parser", Parser)
    assert cli.main([]) == 130
    assert capsys.readouterr().err == (
        "elphel: interrupted: 3 of 8 frames kept in b; the same command captures the rest\n"
    )
