"""docs/testing.md: a user's own project, outside this repository, tested with elphel_rig."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

DOC = Path(__file__).resolve().parents[2] / "docs" / "testing.md"


def _blocks(lang: str) -> dict[str, str]:
    """The page's fenced blocks of ``lang`` whose first line is ``# file: NAME``."""
    out = {}
    for body in re.findall(rf"```{lang}\n(.*?)```", DOC.read_text(), flags=re.S):
        first, _, rest = body.partition("\n")
        if first.startswith("# file: "):
            out[first.removeprefix("# file: ").strip()] = rest
    return out


def _pytest_in(folder: Path, *, timeout: float) -> subprocess.CompletedProcess[str]:
    """Run pytest over ``folder`` as a fresh project: no conftest or rootdir of this repository.

    The fixture comes from the installed elphel-sim's pytest11 entry point only. The run
    has a process group of its own, so a timeout also ends the rig it started.
    """
    env = {k: v for k, v in os.environ.items() if not k.startswith("ELPHEL_")}
    env.pop("PYTEST_ADDOPTS", None)
    args = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(folder)]
    with subprocess.Popen(
        args,
        cwd=folder,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        start_new_session=True,
    ) as run:
        try:
            out, err = run.communicate(timeout=timeout)
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(run.pid, signal.SIGKILL)  # whatever the run left behind
    return subprocess.CompletedProcess(args, run.returncode, out, err)


def test_the_pages_capture_script_and_its_test_pass_in_a_project_of_their_own(
    tmp_path: Path,
) -> None:
    files = _blocks("python")
    assert set(files) == {"capture_one.py", "test_capture_one.py", "test_faults.py"}
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    done = _pytest_in(tmp_path, timeout=240)
    assert done.returncode == 0, done.stdout + done.stderr
    assert re.search(r"\b5 passed\b", done.stdout), done.stdout


def test_a_bad_rig_option_fails_the_test_with_one_line(tmp_path: Path) -> None:
    (tmp_path / "test_bad.py").write_text(
        "import pytest\n\n"
        "@pytest.mark.elphel_rig(scenario='nope')\n"
        "def test_x(elphel_rig):\n    pass\n"
    )
    done = _pytest_in(tmp_path, timeout=120)
    assert done.returncode == 1, done.stdout + done.stderr
    assert "elphel_rig scenario 'nope'; allowed" in done.stdout
