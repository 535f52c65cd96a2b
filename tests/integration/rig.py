"""Helpers of the integration tests: a simulated rig served by `elphel-sim up`, the CLI.

Tests import them from here (``from .rig import run_cli``); conftest.py holds only
fixtures.
"""

from __future__ import annotations

import json
import os
import selectors
import signal
import subprocess
import sys
import time
from typing import Any

import pytest


def start_rig(*extra: str) -> tuple[subprocess.Popen[str], dict[str, Any]]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "elphel_sim.cli", "up", "--json", *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    deadline = time.monotonic() + 60
    line = ""
    while time.monotonic() < deadline and not line:
        if sel.select(timeout=0.5):
            line = proc.stdout.readline()
        if proc.poll() is not None:
            break
    sel.close()
    if not line:
        stderr = stop_rig(proc)
        pytest.fail(f"elphel-sim up printed no JSON line; stderr: {stderr}")
    return proc, json.loads(line)


def stop_rig(proc: subprocess.Popen[str]) -> str:
    """Stop the rig; return what it wrote on stderr."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    stderr = proc.stderr.read() if proc.stderr is not None else ""
    for stream in (proc.stdout, proc.stderr):
        if stream is not None:
            stream.close()
    return stderr


def run_cli(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """Run the `elphel` CLI in a fresh process, as a user's shell would."""
    return subprocess.run(
        [sys.executable, "-m", "elphel_host.cli", *args],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, **(env or {})},
    )
