"""`elphel stage ...` against the simulated stage: one JSON object per command."""

from __future__ import annotations

import json
import re

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
    assert main(["stage", "home", "--stage", sim.tcp_url]) == 0  # the travel is known once homed
    capsys.readouterr()
    for loop in (["--open-loop"], []):
        assert main(["stage", "move", "500", "--stage", sim.tcp_url, *loop]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and re.search(
            r"500 mm is beyond the travel [\d.]+\.\.1[01]\d(\.\d+)? mm$", err[0]
        )


def test_each_stage_keeps_its_own_calibration(sim, capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path))
    stages = tmp_path / "elphel" / "stages"
    with SimStage(seed=4, time_scale=100) as other:
        other.wait_booted()
        other_serial = run(capsys, "status", "--stage", other.tcp_url)["serial"]
        serial = run(capsys, "status", "--stage", sim.tcp_url)["serial"]
        assert other_serial != serial
        # The other stage's calibration, as a real rig's would be.
        stages.mkdir(parents=True)
        theirs = stages / f"{other_serial}.json"
        theirs.write_text('{"mm_per_step": 0.008771, "offset_mm": null, "backlash_mm": 0.02}')
        before = theirs.read_bytes()
        cal = run(capsys, "calibrate", "--stage", sim.tcp_url, "--span-mm", "20", "--repeats", "2")
        assert cal["model"] == str(stages / f"{serial}.json")
        assert theirs.read_bytes() == before
        ours = json.loads((stages / f"{serial}.json").read_text())
        assert ours["mm_per_step"] == pytest.approx(cal["mm_per_step"])
        # Each stage's own file is what its commands load.
        run(capsys, "home", "--stage", other.tcp_url)
        got = run(capsys, "backlash", "--stage", other.tcp_url, "--at-mm", "20", "--repeats", "1")
        assert got["mm_per_step"] == 0.008771


def test_a_missing_model_file_is_an_error(sim, capsys, tmp_path):
    typo = tmp_path / "typo.json"
    assert main(["stage", "move", "20", "--stage", sim.tcp_url, "--model", str(typo)]) == 1
    err = capsys.readouterr().err
    assert str(typo) in err and "does not exist" in err


def test_help_names_the_default_model_file(capsys):
    with pytest.raises(SystemExit):
        main(["stage", "calibrate", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "$XDG_CONFIG_HOME/elphel/stages/SERIAL.json" in out and "~/.config" in out


def test_right_after_home_moves_speak_millimetres(sim, capsys):
    at_home = run(capsys, "home", "--stage", sim.tcp_url)["caliper_mm"]
    # Home is approached from above: the same reading cannot be reached from below.
    assert main(["stage", "move", f"{at_home}", "--stage", sim.tcp_url]) == 1
    err = capsys.readouterr().err
    assert f"{at_home:g} mm is beyond the travel" in err and "step" not in err
    moved = run(capsys, "move", f"{at_home + 0.3}", "--stage", sim.tcp_url)
    assert moved["caliper_mm"] == pytest.approx(at_home + 0.3, abs=0.011)
