"""How the demo acts as a user: the simulated rig, the `elphel` CLI, the lines it prints.

`simulated_rig` runs `elphel-sim up --json` in a child process, `elphel` runs an
`elphel ... --json` command as a user types it (`elphel_sim` an `elphel-sim` one),
`read_frame_metadata` reads the metadata of a TIFF the CLI wrote, and `step` prints one
line of the demo's account. Every step of `elphel_sim.demo` (`make demo`) goes through
these; a failure is a `DemoError`.

While a command runs, its own progress (what it writes on stderr) is relayed to the
demo's progress line on stderr (`DEMO_PROGRESS`): on a terminal one updating line with a
bar over the demo's commands, their rate and the time left, followed by the command's own
line; when stderr is not a terminal, one plain line each. The account (`step`) stays on
stdout.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from elphel_host.progress import ProgressLine


class DemoError(RuntimeError):
    """A demo step failed; the message says which and why."""


@contextmanager
def simulated_rig(
    *, seed: int, scenario: str = "default", firmware: str = "camd", lens_blur_px: float = 0.0
) -> Iterator[dict[str, Any]]:
    """Run `elphel-sim up --json` in a child process; yield its announcement."""
    command = ["up", "--json", "--seed", str(seed), "--scenario", scenario, "--firmware", firmware]
    if lens_blur_px:
        command += ["--lens-blur", str(lens_blur_px)]
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
        stop_child(proc)
        if proc.stdout is not None:
            proc.stdout.close()


def stop_child(proc: subprocess.Popen[Any], *, timeout_s: float = 20.0) -> None:
    """End a child process: SIGTERM, then SIGKILL if it has not exited after ``timeout_s``."""
    if proc.poll() is not None:
        return
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def rig_env(rig: dict[str, Any]) -> dict[str, str]:
    """The environment that points the `elphel` CLI at ``rig``'s camera and stage."""
    return {
        "ELPHEL_CAMERA_URL": rig["camera_url"],
        "ELPHEL_CAMERA_TOKEN": rig["token"],
        "ELPHEL_STAGE_URL": rig["stage_url"],
    }


class DemoProgress:
    """The demo's progress on stderr: its `elphel` commands done of ``total``.

    Each update also shows the running command's own latest progress line.
    """

    def __init__(self, line: ProgressLine | None = None, *, total: int = 0) -> None:
        self.line = line if line is not None else ProgressLine()
        self.total = total
        self.done = 0

    def relay(self, command: str, text: str) -> None:
        """Show the running command's progress ``text`` (one of its stderr lines)."""
        if self.total:
            self.line.update(
                f"demo: {self.done}/{self.total} commands",
                done=self.done,
                total=self.total,
                detail=f"elphel {command}: {text}",
            )

    def command_done(self) -> None:
        self.done += 1

    def say(self, text: str) -> None:
        """A line of the demo's account on stdout, after ending the progress line."""
        self.line.end()
        print(text, flush=True)


DEMO_PROGRESS = DemoProgress()


def step(message: str) -> None:
    DEMO_PROGRESS.say(f"[demo] {message}")


def elphel(*args: str, env: dict[str, str] | None = None) -> dict[str, Any]:
    """Run an `elphel ... --json` command as a user would; return its JSON object.

    Its stderr (progress, then an error if it fails) goes to `DEMO_PROGRESS` line by
    line while it runs.
    """
    cmd = [sys.executable, "-m", "elphel_host.cli", *args, "--json"]
    name = " ".join(a for a in args[:2] if not a.startswith(("-", "/")))
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, **(env or {})},
    )
    assert proc.stdout is not None and proc.stderr is not None
    errors: list[str] = []

    def follow(stream: Any) -> None:
        for raw in stream:
            text = raw.rstrip("\n")
            errors.append(text)
            if text and not text.startswith("elphel: "):
                DEMO_PROGRESS.relay(name, text)

    follower = threading.Thread(target=follow, args=(proc.stderr,), daemon=True)
    follower.start()
    try:
        stdout = proc.stdout.read()
        proc.wait(timeout=1800)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        follower.join(timeout=10)
        proc.stdout.close()
        proc.stderr.close()
    DEMO_PROGRESS.command_done()
    if proc.returncode != 0:
        failed = [e for e in errors if e.startswith("elphel: ")] or errors
        raise DemoError(f"elphel {' '.join(args)}: {' '.join(failed).strip() or proc.returncode}")
    result: dict[str, Any] = json.loads(stdout)
    return result


def elphel_sim(*args: str) -> dict[str, Any]:
    """Run an `elphel-sim ... --json` command (not `up`) as a user would; its JSON object."""
    done = subprocess.run(
        [sys.executable, "-m", "elphel_sim.cli", *args, "--json"],
        capture_output=True,
        text=True,
        timeout=1800,
    )
    if done.returncode != 0:
        message = done.stderr.strip().splitlines()[-1:] or [str(done.returncode)]
        raise DemoError(f"elphel-sim {' '.join(args)}: {message[0]}")
    result: dict[str, Any] = json.loads(done.stdout)
    return result


def read_frame_metadata(path: Path) -> tuple[Any, dict[str, Any]]:
    from elphel_host.camera.client import read_tiff_metadata

    return read_tiff_metadata(path.read_bytes())
