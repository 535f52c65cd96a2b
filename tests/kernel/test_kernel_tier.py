"""The real-kernel tier: Debian's kernel booted once with virtme-ng, the guest tests inside.

One boot (software emulation, no KVM needed) loads vivid and i2c-stub and runs
tests/kernel/guest_v4l2.py under pytest inside the guest; the one test here passes only if
every guest test ran and passed there, and names each one that did not. Needs the Debian packages
qemu-system-x86, linux-image-amd64, v4l-utils and busybox-static, and virtme-ng from PyPI
(requirements-dev.txt); `.ci/run` installs them. A missing one fails with its name.
"""

from __future__ import annotations

import ast
import glob
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
GUEST_MODULE = Path(__file__).with_name("guest_v4l2.py")
BOOT_TIMEOUT_S = 1200  # one boot and its guest tests: 5-9 min on 2 busy cores
MODULES = (
    # Input 0 a webcam (discrete sizes: modes), input 1 HDMI with capture cropping.
    "modprobe vivid n_devs=1 node_types=0x1 num_inputs=2 input_types=0xc ccs_cap_mode=1",
    "modprobe i2c-dev",
    "modprobe i2c-stub chip_addr=0x48",
)


def _guest_tests() -> list[str]:
    tree = ast.parse(GUEST_MODULE.read_text())
    return [
        n.name for n in tree.body if isinstance(n, ast.FunctionDef) and n.name.startswith("test_")
    ]


def _need() -> tuple[str, str]:
    """The kernel image and the vng command, or a failure naming what to install."""
    kernels = sorted(glob.glob("/boot/vmlinuz-*"))
    bin_dir = Path(sys.executable).parent
    vng = shutil.which("vng") or (str(bin_dir / "vng") if (bin_dir / "vng").exists() else None)
    missing = []
    if not kernels:
        missing.append("a kernel in /boot (Debian package linux-image-amd64)")
    if vng is None:
        missing.append("vng (PyPI package virtme-ng, in requirements-dev.txt)")
    for command, package in (
        ("qemu-system-x86_64", "qemu-system-x86"),
        ("v4l2-ctl", "v4l-utils"),
        ("busybox", "busybox-static"),
    ):
        if shutil.which(command) is None:
            missing.append(f"{command} (Debian package {package})")
    if missing:
        pytest.fail("the kernel tier needs " + "; ".join(missing) + " (.ci/run installs them)")
    assert vng is not None
    return kernels[-1], vng


def _guest_script(out: Path) -> str:
    env = {
        "PYTHONPATH": os.environ.get("PYTHONPATH", ""),
        "PYTHONDONTWRITEBYTECODE": "1",
        "PATH": f"{Path(sys.executable).parent}:/usr/sbin:/usr/bin:/sbin:/bin",
    }
    exports = "\n".join(f"export {k}='{v}'" for k, v in env.items())
    pytest_cmd = (
        f"{sys.executable} -m pytest -q -p no:cacheprovider -p no:xdist "
        f"--rootdir={ROOT} --junitxml={out}/junit.xml {GUEST_MODULE}"
    )
    return "\n".join(
        [
            "#!/bin/sh",
            exports,
            *MODULES,
            f"cd {ROOT}",
            f"{pytest_cmd} > {out}/guest.log 2>&1",
            f"echo $? > {out}/rc",
            "",
        ]
    )


@pytest.fixture
def guest(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[str, str]]:
    """Boot once, run the guest tests; each test case's outcome and message by name."""
    kernel, vng = _need()
    out = tmp_path_factory.mktemp("kernel")
    script = out / "guest.sh"
    script.write_text(_guest_script(out))
    script.chmod(0o755)
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}:{os.environ.get('PATH', '')}"}
    cmd = [
        vng,
        "--disable-kvm",
        "--force-9p",
        "--cpus",
        "1",
        "--memory",
        "1G",
        "--rwdir",
        str(out),
        "-r",
        kernel,
        "--exec",
        f"sh {script}",
    ]
    run = subprocess.run(
        cmd,
        env=env,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=BOOT_TIMEOUT_S,
        check=False,
    )
    log = (out / "guest.log").read_text() if (out / "guest.log").exists() else ""
    if not (out / "junit.xml").exists():
        pytest.fail(
            f"the guest ran no tests (vng exit {run.returncode}):\n{run.stdout[-3000:]}\n"
            f"{run.stderr[-3000:]}\n{log[-3000:]}"
        )
    results: dict[str, tuple[str, str]] = {}
    for case in ET.parse(out / "junit.xml").getroot().iter("testcase"):
        problem = next((c for c in case if c.tag in ("failure", "error", "skipped")), None)
        outcome = "passed" if problem is None else problem.tag
        text = "" if problem is None else (problem.get("message", "") + "\n" + (problem.text or ""))
        results[case.get("name", "")] = (outcome, text[-4000:])
    return results


# One test for the whole tier, so that it boots once whichever worker runs it (pytest-xdist
# 3.8's xdist_group marks do not reach the scheduler under pytest 9: parametrized cases
# spread over the workers and each booted its own guest).
@pytest.mark.slow  # boots a kernel under software emulation
def test_every_guest_test_passes_in_one_boot(guest: dict[str, tuple[str, str]]) -> None:
    missing, failed = [], {}
    for name in _guest_tests():
        cases = {k: v for k, v in guest.items() if k == name or k.startswith(name + "[")}
        if not cases:
            missing.append(name)
        failed.update({k: text for k, (outcome, text) in cases.items() if outcome != "passed"})
    assert not missing, f"did not run in the guest: {missing}; ran: {sorted(guest)}"
    assert not failed, f"{len(failed)} of {len(guest)} guest tests failed:\n\n" + "\n\n".join(
        f"{k}:\n{text}" for k, text in failed.items()
    )
