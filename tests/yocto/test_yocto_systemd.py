"""The systemd unit passes `systemd-analyze verify` (Debian's systemd package).

verify checks that ExecStart's program exists and that the unit's dependencies
resolve, so it runs against a temporary root: the filled-in unit in
/etc/systemd/system, a copy of this machine's system units, and an executable
stand-in at the path the package installs the console script to. verify only warns
about unknown keys and bad values (exit 0), so any message it prints fails the test.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.yocto.layer import UNIT_TEMPLATE, daemon_recipe, render_template, unit_exec_start

SYSTEM_UNITS = Path("/usr/lib/systemd/system")


def _systemd_analyze() -> str:
    exe = shutil.which("systemd-analyze")
    if exe is None:
        message = (
            "systemd-analyze is not installed: install Debian's systemd package "
            "(apt-get install --no-install-recommends systemd); .ci/run does this"
        )
        if os.environ.get("CI") == "true":
            pytest.fail(message)
        pytest.skip(message)
    return exe


def _root_with_unit(root: Path, unit_text: str) -> Path:
    (root / "usr" / "lib" / "systemd").mkdir(parents=True)
    if SYSTEM_UNITS.is_dir():
        shutil.copytree(SYSTEM_UNITS, root / "usr" / "lib" / "systemd" / "system", symlinks=True)
    (root / "lib").symlink_to("usr/lib")  # the copied .wants links point into /lib
    program = root / unit_exec_start(unit_text)[0].lstrip("/")
    program.parent.mkdir(parents=True, exist_ok=True)
    program.write_text("#!/bin/sh\nexit 0\n")
    program.chmod(0o755)
    unit = root / "etc" / "systemd" / "system" / UNIT_TEMPLATE.name
    unit.parent.mkdir(parents=True)
    unit.write_text(unit_text)
    return unit


def _verify(exe: str, root: Path, unit: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [exe, "verify", "--man=no", f"--root={root}", str(unit)],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "SYSTEMD_LOG_COLOR": "0", "SYSTEMD_PAGER": ""},
    )


def test_unit_is_valid(tmp_path: Path) -> None:
    exe = _systemd_analyze()
    unit = _root_with_unit(tmp_path, render_template(UNIT_TEMPLATE, daemon_recipe()))
    result = _verify(exe, tmp_path, unit)
    messages = (result.stdout + result.stderr).strip()
    assert result.returncode == 0 and not messages, messages


def test_verify_in_this_setup_reports_a_broken_unit(tmp_path: Path) -> None:
    exe = _systemd_analyze()
    text = render_template(UNIT_TEMPLATE, daemon_recipe())
    broken = text.replace("Restart=on-failure", "Restart=sometimes\nExecStrat=/bin/true")
    unit = _root_with_unit(tmp_path, broken)
    messages = _verify(exe, tmp_path, unit).stderr
    assert "Unknown key" in messages and "restart" in messages.lower()
