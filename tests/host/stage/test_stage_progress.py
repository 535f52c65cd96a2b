"""`elphel stage move` reports its progress in millimetres (rate with its unit)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from elphel_host.cli import main
from elphel_sim.stage_server import SimStage


def test_move_progress_is_in_mm(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("HOME", str(tmp_path))  # the nominal stage model: no saved one
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    with SimStage(seed=5, time_scale=100) as sim:
        sim.wait_booted()
        url = ["--stage", sim.tcp_url]
        assert main(["stage", "home", *url, "--json"]) == 0
        capsys.readouterr()
        assert main(["stage", "move", "20", *url, "--open-loop", "--json"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    rates = [line for line in err if "/s" in line]
    assert rates, err
    for line in rates:  # "(3.52 mm/s, 0:04 left)", never a bare "(417/s, ...)"
        assert re.search(r"\([\d.,]+ mm/s, \d+:\d\d left\)", line), line
