"""Browser tests: the page in Debian's headless Chromium and Firefox against `elphel-sim up`.

Chromium (test_page.py) is driven by Playwright: /usr/bin/chromium (Debian's ``chromium``
package) unless ``ELPHEL_CHROMIUM`` names another binary. Firefox (test_firefox.py) is
driven over the WebDriver BiDi it serves itself (bidi.py, firefox.py; Debian has no
geckodriver, and Playwright drives only its own patched Firefox build): /usr/bin/firefox-esr
(Debian's ``firefox-esr`` package) unless ``ELPHEL_FIREFOX`` names another binary. Without
a browser its tests fail, so CI cannot pass them silently; set ``ELPHEL_BROWSER_TESTS=skip``
to skip them on a machine that has no browser.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import urlsplit

import httpx
import pytest

from elphel_sim.pytest_plugin import Rig, start_rig, stop_rig

if TYPE_CHECKING:
    from tests.browser.bidi import Session

CHROMIUM = os.environ.get("ELPHEL_CHROMIUM", "/usr/bin/chromium")
FIREFOX = os.environ.get("ELPHEL_FIREFOX", "/usr/bin/firefox-esr")
# Screenshots go to a scratch folder, so a test run leaves the checkout as it was;
# ELPHEL_SCREENSHOTS=docs/img refreshes the pictures of docs/browser.md.
SCREENSHOTS = Path(
    os.environ.get("ELPHEL_SCREENSHOTS") or Path(tempfile.gettempdir()) / "elphel-screenshots"
)


def _browser_binary(name: str, wanted: str, package: str, variable: str) -> str:
    path = shutil.which(wanted) or (wanted if os.access(wanted, os.X_OK) else None)
    if path is None:
        if os.environ.get("ELPHEL_BROWSER_TESTS") == "skip":
            pytest.skip(f"no {name} at {wanted} and ELPHEL_BROWSER_TESTS=skip")
        pytest.fail(
            f"no {name} at {wanted}: install Debian's {package} package (or set "
            f"{variable}; ELPHEL_BROWSER_TESTS=skip skips these tests)",
            pytrace=False,
        )
    return path


def _chromium() -> str:
    return _browser_binary("Chromium", CHROMIUM, "chromium", "ELPHEL_CHROMIUM")


def _firefox() -> str:
    return _browser_binary("Firefox", FIREFOX, "firefox-esr", "ELPHEL_FIREFOX")


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


@pytest.fixture(scope="package")
def firefox(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Session]:
    """Headless Firefox ESR and one WebDriver BiDi session with it (see firefox.py)."""
    executable = _firefox()
    from tests.browser.bidi import Session
    from tests.browser.firefox import Firefox

    process = Firefox(executable, tmp_path_factory.mktemp("firefox"))
    try:
        session = Session(process.url)
        try:
            yield session
        finally:
            session.close_browser()
    finally:
        process.stop()


def outside_requests(urls: list[str], camera_url: str) -> list[str]:
    """The requested URLs that leave the camera's origin (blob: and data: URLs stay)."""
    origin = urlsplit(camera_url)[:2]
    fetched = [u for u in urls if not u.startswith(("blob:", "data:"))]
    return [u for u in fetched if urlsplit(u)[:2] != origin]


def rest(rig: Rig, path: str) -> Any:
    """A public read of the daemon's REST API (``path`` after /api/v1)."""
    r = httpx.get(f"{rig.camera_url}/api/v1{path}", timeout=30)
    r.raise_for_status()
    return r.json()


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
