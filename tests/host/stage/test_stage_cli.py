"""`elphel stage ...` against the simulated stage: one JSON object per command."""

from __future__ import annotations

import json

import pytest

from elphel_host.cli import main
from elphel_sim.stage_server import SimStage


@pytest.fixture(scope="module")
def sim():
    with SimStage(seed=3, time_scale=100) as s:
        s.wait_booted()
        yield s


def run(capsys, *argv: str) -> dict:
    assert main(["stage", *argv, "--json"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1, out
    return json.loads(out[0])


def test_cli_session(sim, capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("ELPHEL_STAGE_URL", sim.tcp_url)
    model = str(tmp_path / "model.json")
    assert run(capsys, "home")["homed"] is True
    cal = run(capsys, "calibrate", "--model", model, "--span-mm", "40", "--repeats", "2")
    assert cal["mm_per_step"] == pytest.approx(0.008778, rel=1e-3)
    assert "spread_mm_per_step" in cal
    assert run(capsys, "backlash", "--model", model, "--at-mm", "30")[
        "backlash_mm"
    ] == pytest.approx(0.05, abs=0.015)
    moved = run(capsys, "move", "25.0", "--model", model)
    truth = sim.sim_state()["true_mm"] - sim.sim_state()["caliper_zero_mm"]
    assert abs(truth - 25.0) <= 0.01 and moved["closed_loop"] is True
    st = run(capsys, "status", "--stage", sim.tcp_url)
    assert st["caliper_mm"] == pytest.approx(25.0, abs=0.011) and isinstance(st["steps"], int)
    rel = run(capsys, "move", "1.0", "--relative", "--open-loop", "--model", model)
    assert rel["closed_loop"] is False
    assert "steps" in run(capsys, "stop")
    assert run(capsys, "zero")["zeroed"] == "steps"
    assert isinstance(run(capsys, "list")["boards"], list)


def test_cli_errors_are_one_line(sim, capsys, monkeypatch):
    monkeypatch.delenv("ELPHEL_STAGE_URL", raising=False)
    assert main(["stage", "status"]) == 1
    assert "ELPHEL_STAGE_URL" in capsys.readouterr().err
    assert main(["stage", "move", "500", "--stage", sim.tcp_url, "--open-loop"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "soft limits" in err[0]
