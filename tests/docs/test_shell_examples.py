"""The README's and docs' shell examples, run line by line against a simulated rig.

A block is taken from the page as it is, so an example that stops working (a renamed
option, a changed output) fails here. Only what a reader replaces by hand is replaced:
the `elphel-sim up` and `export` lines (the fixture's rig stands in for them, its URLs
in the same variables), and lines naming a placeholder (QUAD_DIR) or another simulator
(the quad example needs `--scenario quad`, which has its own test in
tests/integration). Every other line must exit 0.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow
QUICKSTART = (ROOT / "docs" / "quickstart.md", "## 5. Set, capture and follow from the host")


def sh_block(page: Path, heading: str) -> list[str]:
    """The command lines of the first ``sh`` block after ``heading`` (comments dropped)."""
    text = page.read_text()
    at = text.index(heading)
    body = re.search(r"```sh\n(.*?)```", text[at:], flags=re.S)
    assert body is not None, f"{page.name}: no sh block after {heading!r}"
    return [
        line
        for line in body.group(1).splitlines()
        if line.strip() and not line.lstrip().startswith("#")
    ]


def runnable(lines: list[str]) -> tuple[list[str], list[str]]:
    """The lines to run and those left out (with why, for the failure message)."""
    run, left = [], []
    for line in lines:
        if "elphel-sim up" in line and not line.startswith("#"):
            left.append(f"{line}  (the fixture's rig)")
        elif line.startswith("export "):
            left.append(f"{line}  (the fixture's URLs)")
        elif "QUAD_DIR" in line or "tp capture" in line:
            left.append(f"{line}  (a placeholder / the quad simulator)")
        else:
            run.append(line)
    return run, left


def run_lines(
    lines: list[str], rig, cwd: Path, prepare=lambda line: line, again_if: str | None = None
) -> None:
    """Run each line in bash; ``prepare`` rewrites a line before each run of it.

    ``again_if``: a line whose stderr says this is prepared and run again (3 runs at most),
    for a line that names something as fleeting as a recent frame.
    """
    env = {k: v for k, v in os.environ.items() if not k.startswith("ELPHEL_")}
    env |= {
        "ELPHEL_CAMERA_URL": rig.camera_url,
        "ELPHEL_CAMERA_TOKEN": rig.token,
        "ELPHEL_STAGE_URL": rig.stage_url,
    }
    # `.venv/bin/elphel` in the README is the project's venv: the one running the tests.
    (cwd / ".venv").mkdir()
    (cwd / ".venv" / "bin").symlink_to(Path(sys.executable).parent)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    for given in lines:
        for _ in range(3):
            line = prepare(given)
            done = subprocess.run(
                ["bash", "-c", f"set -e -o pipefail\n{line}\n"],
                cwd=cwd,
                env=env,
                capture_output=True,
                text=True,
                timeout=600,
            )
            if done.returncode == 0 or again_if is None or again_if not in done.stderr:
                break
        assert done.returncode == 0, f"{line}\n{done.stdout}\n{done.stderr}"


def test_readme_by_hand(elphel_rig, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    lines, left = runnable(sh_block(ROOT / "README.md", "## By hand"))
    assert len(lines) >= 7, left
    monkeypatch.setenv("HOME", str(tmp_path))  # the stage model's default place
    run_lines(lines, elphel_rig, tmp_path)
    assert (tmp_path / "frame.tif").exists() and (tmp_path / "frame.png").exists()
    assert (tmp_path / "fused.tif").exists() and (tmp_path / "burst").is_dir()


def test_quickstart_set_capture_follow(elphel_rig, tmp_path: Path) -> None:
    lines, left = runnable(sh_block(*QUICKSTART))
    assert len(lines) == 6, left
    from elphel_host.camera.client import CameraClient

    def recent_frame(line: str) -> str:
        # The ring-buffer example names frame 1234; ask for one the rig will still have
        # when the CLI has started: the ring holds the last 64 frames (about 6 s here),
        # and a capture waits for a frame up to 14 ahead, so a frame 12 ahead stays there
        # for some 8 s after this. A busy machine (four test workers on two cores) can take
        # longer to start the CLI: the line is then run again, with a new frame.
        if "--frame 1234" not in line:
            return line
        with CameraClient(elphel_rig.camera_url, elphel_rig.token) as cam:
            recent = cam.frame()["frame"]
        return line.replace("--frame 1234", f"--frame {recent + 12}")

    gone = "is no longer in the ring buffer"
    run_lines(lines, elphel_rig, tmp_path, prepare=recent_frame, again_if=gone)
    assert (tmp_path / "again.tif").exists()
