"""The camera's browser page in headless Firefox ESR against a live simulated rig.

The Firefox counterpart of test_page.py's core checks, driven over WebDriver BiDi
(bidi.py): the page loads clean, the live view advances, the exposure control reaches the
camera, and a screenshot (page-firefox.png, in conftest.SCREENSHOTS). Results are
checked over REST, not in the page's own state.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from typing import Any
from urllib.parse import urlsplit

import pytest

from tests.browser.bidi import Session, Tab
from tests.browser.conftest import SCREENSHOTS, outside_requests, rest

pytestmark = pytest.mark.slow


class Opened:
    """The page on the camera in a new tab; with ``token``, typed into the token field."""

    def __init__(self, firefox: Session, rig: Any, *, token: str | None) -> None:
        self.tab = Tab(firefox, width=1280, height=900)
        self.tab.navigate(rig.camera_url + "/")
        if token is not None:
            self.tab.click("#token")
            self.tab.type(token)
            self.tab.click("#token-form button[type=submit]")
            accepted = "document.getElementById('token-state').dataset.state === 'accepted'"
            self.tab.wait_for(accepted, timeout_s=30)
        self.tab.wait_for("document.querySelector('#live[data-frame]') !== null", timeout_s=60)

    def frame(self) -> int:
        return int(self.tab.attribute("#live", "data-frame") or -1)

    def close(self) -> None:
        self.tab.close()


@pytest.fixture
def opened(firefox: Session, default_rig: Any) -> Iterator[Opened]:
    o = Opened(firefox, default_rig, token=default_rig.token)
    yield o
    o.close()


def test_page_loads_in_firefox_without_errors_or_outside_requests(firefox, default_rig):
    o = Opened(firefox, default_rig, token=None)
    try:
        o.tab.wait_for("document.querySelector('[name=EXPOS]') !== null")
        time.sleep(2)  # the histogram and the event log start
        assert o.tab.errors == []
        urls = [u for _, u in o.tab.requests]
        assert outside_requests(urls, default_rig.camera_url) == []
        assert any("/preview.mjpeg" in u for u in urls)
        assert any("/histogram" in u for u in urls)
    finally:
        o.close()


def test_the_live_view_advances_in_firefox(opened):
    seen = []
    started = time.monotonic()
    while time.monotonic() - started < 6:
        seen.append(opened.frame())
        time.sleep(0.1)
    distinct = sorted(set(seen))
    assert seen == sorted(seen)  # never goes back
    fps = float(opened.tab.evaluate("document.getElementById('live-fps').textContent"))
    assert 0.5 <= fps <= 10.5
    assert len(distinct) >= 0.6 * fps * 6
    # The picture of the last frame is decoded, at the size the stream said. A new frame
    # replaces the picture ten times a second, and the one just set may still be decoding
    # (complete is false until it is): read the sizes once the current one is decoded.
    size = opened.tab.wait_for(
        "live.complete ? [live.naturalWidth, Number(live.dataset.width)] : null", timeout_s=10
    )
    scale = int(opened.tab.attribute("#live", "data-scale") or 0)
    assert size == [320 // scale, 320]


def test_exposure_control_sets_expos_and_shows_the_frame_it_took_effect_in_firefox(
    opened, default_rig
):
    tab = opened.tab
    schema = rest(default_rig, "/ports/0/params/schema")["params"]["EXPOS"]
    position = 540  # about 7 ms: a well-exposed picture for the screenshot
    lo, hi = math.log(max(schema["minimum"], 1)), math.log(schema["maximum"])
    wanted_us = round(math.exp(lo + position / 1000 * (hi - lo)))
    before = rest(default_rig, "/ports/0/params")["EXPOS"]
    assert abs(before - wanted_us) > 100
    slider = tab.element("input[type=range][name=EXPOS]")
    earlier = len(tab.requests)  # the token's check, an empty PATCH, came before
    tab.call(
        "(el, v) => { el.focus(); el.value = String(v);"
        " el.dispatchEvent(new Event('input', {bubbles: true}));"
        " el.dispatchEvent(new Event('change', {bubbles: true})); }",
        slider,
        position,
    )
    effect = "document.querySelector('[data-effect-for=EXPOS]')"
    tab.wait_for(f"{effect}.dataset.inEffect === 'true'")
    at = int(tab.evaluate(f"{effect}.dataset.frame"))
    assert f"in effect from frame {at}" in tab.evaluate(f"{effect}.textContent")
    patched = [urlsplit(u).path for method, u in tab.requests[earlier:] if method == "PATCH"]
    assert patched == ["/api/v1/ports/0/params"]
    params = rest(default_rig, "/ports/0/params")
    row_us = params["EXPOS"] / params["VEXPOS"]
    assert abs(params["EXPOS"] - wanted_us) <= row_us  # EXPOS is rounded to whole rows
    # The frame shown is the one from which the camera has the new exposure.
    assert rest(default_rig, f"/ports/0/params?frame={at}")["EXPOS"] == params["EXPOS"]
    assert rest(default_rig, f"/ports/0/params?frame={at - 1}")["EXPOS"] == before
    assert opened.frame() >= at
    # The field shows the value read back, in ms.
    field = tab.evaluate("document.querySelector('input[type=number][name=EXPOS]').value")
    assert abs(float(field) - params["EXPOS"] / 1000) < 1e-3


def test_a_screenshot_of_the_page_in_firefox(opened):
    tab = opened.tab
    tab.wait_for("document.getElementById('hist-text').textContent.startsWith('frame ')")
    time.sleep(1.5)  # a histogram and a few event lines
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    png = tab.screenshot(SCREENSHOTS / "page-firefox.png")
    assert png.startswith(b"\x89PNG\r\n\x1a\n")
    width, height = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
    root = "document.documentElement"
    assert [width, height] == tab.evaluate(f"[{root}.scrollWidth, {root}.scrollHeight]")
    assert height >= 900
    assert tab.errors == []
