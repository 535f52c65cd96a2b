"""Browser tests: Debian's headless Chromium driven by Playwright against `elphel-sim up`.

Chromium is /usr/bin/chromium (Debian's ``chromium`` package) unless ``ELPHEL_CHROMIUM``
names another binary. Without it the tests fail, so CI cannot pass them silently; set
``ELPHEL_BROWSER_TESTS=skip`` to skip them on a machine that has no Chromium.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from elphel_sim.pytest_plugin import Rig, start_rig, stop_rig

CHROMIUM = os.environ.get("ELPHEL_CHROMIUM", "/usr/bin/chromium")
DOCS_IMG = Path(__file__).resolve().parents[2] / "docs" / "img"


def _chromium() -> str:
    path = shutil.which(CHROMIUM) or (CHROMIUM if os.access(CHROMIUM, os.X_OK) else None)
    if path is None:
        if os.environ.get("ELPHEL_BROWSER_TESTS") == "skip":
            pytest.skip(f"no Chromium at {CHROMIUM} and ELPHEL_BROWSER_TESTS=skip")
        pytest.fail(
            f"no Chromium at {CHROMIUM}: install Debian's chromium package (or set "
            "ELPHEL_CHROMIUM; ELPHEL_BROWSER_TESTS=skip skips these tests)",
            pytrace=False,
        )
    return path


@pytest.fixture(scope="package")
def browser() -> Iterator[object]:
    """Chromium for the tests of this package only: Playwright's sync API keeps an asyncio
    loop running in the main thread while it is open, which other tests' loops cannot
    share."""
    executable = _chromium()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=executable, headless=True)
        yield b
        b.close()


def rig_of(scenario: str, *, public_reads: bool = True) -> Iterator[Rig]:
    """A rig whose reads are open by default (the lab's read-only use of the page)."""
    started = start_rig(scenario=scenario, seed=1, public_reads=public_reads)
    try:
        yield started.rig
    finally:
        stop_rig(started.proc)


@pytest.fixture(scope="module")
def default_rig() -> Iterator[Rig]:
    """The default scenario (one MT9P006), its window made small so frames render fast."""
    for rig in rig_of("default"):
        small_window(rig, 0)
        yield rig


def small_window(rig: Rig, port: int) -> None:
    patch = {"WOI_WIDTH": 320, "WOI_HEIGHT": 240, "WOI_LEFT": 1136, "WOI_TOP": 852}
    r = httpx.patch(
        f"{rig.camera_url}/api/v1/ports/{port}/params",
        json=patch,
        headers={"Authorization": f"Bearer {rig.token}"},
        timeout=30,
    )
    r.raise_for_status()
