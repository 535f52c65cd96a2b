"""Helpers of the integration tests: a simulated rig served by `elphel-sim up`, the CLI.

Tests import them from here (``from .rig import run_cli``); conftest.py holds only
fixtures.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from elphel_host.stage.model import StageModel
from elphel_sim import pytest_plugin as plugin
from elphel_sim.cli import build_parser


def start_rig(*extra: str) -> tuple[subprocess.Popen[str], dict[str, Any]]:
    """Start a rig with `elphel-sim up` options; return the process and its announcement.

    The same start as the ``elphel_rig`` fixture of elphel-sim's pytest plugin (which
    tests wanting a rig of their own use); these helpers serve the rigs shared by a
    module or the session.
    """
    args = build_parser().parse_args(["up", *extra])
    try:
        started = plugin.start_rig(scenario=args.scenario, seed=args.seed, firmware=args.firmware)
    except plugin.RigStartError as e:
        pytest.fail(str(e))
    return started.proc, dataclasses.asdict(started.rig)


stop_rig = plugin.stop_rig


@contextlib.contextmanager
def running_rig(*extra: str) -> Iterator[dict[str, Any]]:
    """`start_rig`, yield its announcement, stop it and check that it exited cleanly."""
    proc, announce = start_rig(*extra)
    try:
        yield announce
    finally:
        stderr = stop_rig(proc)
        assert proc.returncode == 0, f"elphel-sim up exited {proc.returncode}: {stderr}"


def run_cli(
    *args: str, env: dict[str, str] | None = None, timeout: float = 120
) -> subprocess.CompletedProcess[str]:
    """Run the `elphel` CLI in a fresh process, as a user's shell would."""
    return subprocess.run(
        [sys.executable, "-m", "elphel_host.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, **(env or {})},
    )


def nominal_model(folder: Path) -> Path:
    """A stage calibration file with the nominal mm/step (closed loop does the rest)."""
    path = folder / "nominal-model.json"
    StageModel().save(path)
    return path
