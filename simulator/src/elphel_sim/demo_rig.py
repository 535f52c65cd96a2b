"""How the demo acts as a user: the simulated rig, the `elphel` CLI, the lines it prints.

`simulated_rig` runs `elphel-sim up --json` in a child process, `elphel` runs an
`elphel ... --json` command as a user types it, `read_frame_metadata` reads the metadata of
a TIFF the CLI wrote, and `step` prints one line of the demo's account. Every step of
`elphel_sim.demo` (`make demo`) goes through these; a failure is a `DemoError`.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any


class DemoError(RuntimeError):
    """A demo step failed; the message says which and why."""


@contextmanager
def simulated_rig(
    *, seed: int, scenario: str = "default", firmware: str = "camd"
) -> Iterator[dict[str, Any]]:
    """Run `elphel-sim up --json` in a child process; yield its announcement."""
    command = ["up", "--json", "--seed", str(seed), "--scenario", scenario, "--firmware", firmware]
    proc = subprocess.Popen(
        [sys.executable, "-m", "elphel_sim.cli", *command],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        if not line:
            raise DemoError(f"elphel-sim up exited with code {proc.wait()} before serving")
        yield json.loads(line)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()


def step(message: str) -> None:
    print(f"[demo] {message}", flush=True)


def elphel(*args: str, env: dict[str, str] | None = None) -> dict[str, Any]:
    """Run an `elphel ... --json` command as a user would; return its JSON object."""
    cmd = [sys.executable, "-m", "elphel_host.cli", *args, "--json"]
    done = subprocess.run(
        cmd, capture_output=True, text=True, env={**os.environ, **(env or {})}, timeout=1800
    )
    if done.returncode != 0:
        raise DemoError(f"elphel {' '.join(args)}: {done.stderr.strip() or done.returncode}")
    result: dict[str, Any] = json.loads(done.stdout)
    return result


def read_frame_metadata(path: Path) -> tuple[Any, dict[str, Any]]:
    from elphel_host.camera.client import read_tiff_metadata

    return read_tiff_metadata(path.read_bytes())
