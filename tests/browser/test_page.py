"""The camera's browser page in headless Chromium against a live simulated rig.

Each test drives the page the way a user does (slider, typing, dragging on the picture,
the token field) and checks the result over REST, not in the page's own state. The
screenshots in docs/browser.md are taken here (browser-*.png, in conftest.SCREENSHOTS).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from typing import Any

import httpx
import pytest

from tests.browser.conftest import SCREENSHOTS, outside_requests, rest, rig_of, small_window

pytestmark = pytest.mark.slow


class Opened:
    """A page on the camera with what it logged and requested."""

    def __init__(self, browser: Any, rig: Any, *, token: str | None) -> None:
        self.context = browser.new_context(viewport={"width": 1280, "height": 900})
        self.page = self.context.new_page()
        self.errors: list[str] = []
        self.requests: list[str] = []
        self.page.on("console", lambda m: self.errors.append(m.text) if m.type == "error" else None)
        self.page.on("pageerror", lambda e: self.errors.append(str(e)))
        self.page.on("request", lambda r: self.requests.append(r.url))
        self.page.goto(rig.camera_url + "/")
        if token is not None:
            self.page.fill("#token", token)
            self.page.click("#token-form button[type=submit]")
            self.page.wait_for_selector("#token-state[data-state=accepted]", timeout=30_000)
        self.page.wait_for_selector("#live[data-frame]", timeout=60_000)

    def frame(self) -> int:
        return int(self.page.get_attribute("#live", "data-frame") or -1)

    def close(self) -> None:
        self.context.close()


@pytest.fixture
def opened(browser: Any, default_rig: Any) -> Iterator[Opened]:
    o = Opened(browser, default_rig, token=default_rig.token)
    yield o
    o.close()


def test_page_loads_without_console_errors_or_outside_requests(browser, default_rig):
    o = Opened(browser, default_rig, token=None)
    try:
        o.page.wait_for_selector("[name=EXPOS]", state="attached")
        time.sleep(2)  # the histogram and the event log start
        assert o.errors == []
        assert outside_requests(o.requests, default_rig.camera_url) == []
        assert any("/preview.mjpeg" in u for u in o.requests)
    finally:
        o.close()


def test_exposure_slider_sets_expos_and_shows_the_frame_it_took_effect(opened, default_rig):
    page = opened.page
    schema = rest(default_rig, "/ports/0/params/schema")["params"]["EXPOS"]
    position = 540  # about 7 ms: a well-exposed picture for the screenshot
    lo, hi = math.log(max(schema["minimum"], 1)), math.log(schema["maximum"])
    wanted_us = round(math.exp(lo + position / 1000 * (hi - lo)))
    before = rest(default_rig, "/ports/0/params")["EXPOS"]
    assert abs(before - wanted_us) > 100
    slider = page.locator("input[type=range][name=EXPOS]")
    slider.focus()
    with page.expect_response(lambda r: r.request.method == "PATCH") as patched:
        slider.evaluate(
            "(el, v) => { el.value = String(v);"
            " el.dispatchEvent(new Event('input', {bubbles: true}));"
            " el.dispatchEvent(new Event('change', {bubbles: true})); }",
            position,
        )
    answer = patched.value.json()
    assert patched.value.request.post_data_json == {"EXPOS": wanted_us}
    effect = page.locator("[data-effect-for=EXPOS]")
    page.wait_for_function(
        "() => document.querySelector('[data-effect-for=EXPOS]').dataset.inEffect === 'true'",
        timeout=30_000,
    )
    at = int(effect.get_attribute("data-frame") or -1)
    assert at == answer["frame"]
    assert f"in effect from frame {at}" in effect.inner_text()
    params = rest(default_rig, "/ports/0/params")
    row_us = params["EXPOS"] / params["VEXPOS"]
    assert abs(params["EXPOS"] - wanted_us) <= row_us  # EXPOS is rounded to whole rows
    assert params["EXPOS"] == answer["params"]["EXPOS"]
    assert opened.frame() >= at
    # The field shows the value read back, in ms.
    field = page.locator("input[type=number][name=EXPOS]")
    assert abs(float(field.input_value()) - params["EXPOS"] / 1000) < 1e-3


def test_dragging_on_the_view_sets_the_snapped_window_and_the_view_changes_shape(
    opened, default_rig
):
    page = opened.page
    before = rest(default_rig, "/ports/0/params")
    box = page.locator("#live").bounding_box()
    assert box is not None
    # Drag from 10 %, 20 % to 61 %, 57 % of the picture: about 163 x 89 of the 320 x 240.
    x0, y0 = box["x"] + 0.10 * box["width"], box["y"] + 0.20 * box["height"]
    x1, y1 = box["x"] + 0.61 * box["width"], box["y"] + 0.57 * box["height"]
    page.mouse.move(x0, y0)
    page.mouse.down()
    page.mouse.move((x0 + x1) / 2, (y0 + y1) / 2, steps=4)
    page.mouse.move(x1, y1, steps=4)
    shown = page.locator("#woi-values").inner_text()
    page.mouse.up()
    page.wait_for_function(
        "() => document.querySelector('#woi-values').dataset.frame !== undefined", timeout=30_000
    )
    after = rest(default_rig, "/ports/0/params")
    for name in ("WOI_LEFT", "WOI_TOP", "WOI_WIDTH", "WOI_HEIGHT"):
        assert after[name] % 2 == 0, name
    assert f"{after['WOI_WIDTH']}×{after['WOI_HEIGHT']}" in shown
    assert abs(after["WOI_WIDTH"] - 0.51 * before["WOI_WIDTH"]) <= 4
    assert abs(after["WOI_HEIGHT"] - 0.37 * before["WOI_HEIGHT"]) <= 4
    assert abs(after["WOI_LEFT"] - (before["WOI_LEFT"] + 0.10 * before["WOI_WIDTH"])) <= 4
    assert abs(after["WOI_TOP"] - (before["WOI_TOP"] + 0.20 * before["WOI_HEIGHT"])) <= 4
    # The live view takes the new shape (at the scale the page chose for it).
    page.wait_for_timeout(500)
    factor = int(page.get_attribute("#live", "data-scale") or 0)
    assert factor in (1, 2, 4, 8)
    w, h = after["WOI_WIDTH"] // factor, after["WOI_HEIGHT"] // factor
    page.wait_for_function(
        f"() => live.naturalWidth === {w} && live.naturalHeight === {h}", timeout=30_000
    )
    assert page.get_attribute("#live", "data-width") == str(after["WOI_WIDTH"])
    small_window(default_rig, 0)


def test_a_bad_value_shows_the_daemons_error_with_the_range_and_changes_nothing(
    opened, default_rig
):
    page = opened.page
    before = rest(default_rig, "/ports/0/params")
    field = page.locator("input[type=number][name=WOI_WIDTH]")
    error = page.locator("[data-error-for=WOI_WIDTH]")
    # Odd: refused by the schema (every sensor's edges are even). Even but wider than the
    # sensor: allowed by the schema, refused by the MT9P006 with its own range.
    for value, allowed in (("333", "(even)"), ("4000", "2..2592 (even)")):
        page.evaluate(
            "() => { document.querySelector('[data-error-for=WOI_WIDTH]').textContent = '' }"
        )
        field.fill(value)
        field.press("Enter")
        page.wait_for_function(
            "() => document.querySelector('[data-error-for=WOI_WIDTH]').textContent !== ''",
            timeout=15_000,
        )
        text = error.inner_text()
        assert value in text and allowed in text, text
    time.sleep(0.5)
    after = rest(default_rig, "/ports/0/params")
    assert {k: v for k, v in after.items() if k != "FRAME"} == {
        k: v for k, v in before.items() if k != "FRAME"
    }


def test_a_change_at_frame_plus_k_is_scheduled_k_frames_ahead(opened, default_rig):
    page = opened.page
    page.check("input[name=when][value=ahead]")
    page.fill("#ahead", "6")
    field = page.locator("input[type=number][name=GAINB]")
    field.fill("1.5")
    with page.expect_response(lambda r: r.request.method == "PATCH") as patched:
        field.press("Enter")
    assert "ahead=6" in patched.value.url
    answer = patched.value.json()
    # Scheduled, not yet in effect: the frame before still has the old gain.
    assert rest(default_rig, f"/ports/0/params?frame={answer['frame'] - 1}")["GAINB"] == 0x10000
    assert rest(default_rig, f"/ports/0/params?frame={answer['frame']}")["GAINB"] == 0x18000
    effect = page.locator("[data-effect-for=GAINB]")
    page.wait_for_function(
        "() => document.querySelector('[data-effect-for=GAINB]').dataset.inEffect === 'true'",
        timeout=30_000,
    )
    assert f"in effect from frame {answer['frame']}" in effect.inner_text()
    assert rest(default_rig, "/ports/0/params")["GAINB"] == 0x18000
    page.check("input[name=when][value=now]")


def test_the_live_view_advances_at_the_streams_rate(opened, default_rig):
    page = opened.page
    seen = []
    started = time.monotonic()
    while time.monotonic() - started < 6:
        seen.append(opened.frame())
        time.sleep(0.1)
    distinct = sorted(set(seen))
    assert distinct == sorted(distinct) and seen == sorted(seen)  # never goes back
    # A frame per picture of the stream: the page's fps is the stream's, and it shows
    # at least that many new frames (the stream's rate, 10 fps at most, bounds it).
    fps = float(page.locator("#live-fps").inner_text())
    assert 0.5 <= fps <= 10.5
    assert len(distinct) >= 0.6 * fps * 6


def refused(page: Any) -> None:
    """A wrong token was used: the page says so and offers no change or capture."""
    page.wait_for_selector("#token-state[data-state=refused]", timeout=30_000)
    assert page.locator("#token-state").inner_text() == "token refused"
    assert page.locator("#needs-token").is_visible()
    assert "token refused" in page.locator("#needs-token").inner_text()
    assert page.locator("#param-form").get_attribute("disabled") is not None
    assert page.locator("#capture-form").get_attribute("disabled") is not None
    assert page.locator("#capture-one").is_disabled()


def test_with_protected_reads_the_page_asks_for_the_token_and_then_shows_the_view(browser):
    for rig in rig_of("default", public_reads=False):
        small_window(rig, 0)
        protected_reads_page(browser, rig)


def protected_reads_page(browser: Any, rig: Any) -> None:
    """No read before a token is accepted; a wrong one refused; the right one shows all."""
    context = browser.new_context(viewport={"width": 1280, "height": 900})
    try:
        page = context.new_page()
        errors: list[str] = []
        api: list[str] = []
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("request", lambda r: api.append(r.url) if "/api/v1/" in r.url else None)
        page.goto(rig.camera_url + "/")
        page.wait_for_selector("#needs-token", state="visible", timeout=30_000)
        assert "needs the token" in page.locator("#needs-token").inner_text()
        assert page.locator("#token-state").inner_text() == "no token"
        time.sleep(3)  # the histogram's and the view's turns come and go
        # No read that needs the token is sent, so no 401 shows as a console error.
        assert errors == []
        assert api == []
        assert page.get_attribute("#live", "data-frame") is None
        page.fill("#token", "not-the-token")
        page.click("#token-form button[type=submit]")
        refused(page)
        time.sleep(2)
        assert page.get_attribute("#live", "data-frame") is None
        assert page.evaluate("() => sessionStorage.length") == 0  # not sent again
        page.fill("#token", rig.token)
        page.click("#token-form button[type=submit]")
        page.wait_for_selector("#live[data-frame]", timeout=60_000)
        assert page.locator("#token-state").inner_text() == "token accepted"
        assert page.locator("#needs-token").is_hidden()
        assert page.locator("[name=EXPOS]").count() >= 1
        assert page.locator("#capture-one").is_enabled()
    finally:
        context.close()


def test_without_a_token_the_controls_need_it_and_with_it_they_work(browser, default_rig):
    o = Opened(browser, default_rig, token=None)
    try:
        page = o.page
        assert page.locator("#needs-token").is_visible()
        assert "needs the token" in page.locator("#needs-token").inner_text()
        assert page.locator("#param-form").get_attribute("disabled") is not None
        assert page.locator("input[type=number][name=GAINR]").is_disabled()
        # A wrong token (reads are public here, so a change proves it): refused, and
        # the controls and capture stay disabled.
        page.fill("#token", "not-the-token")
        page.click("#token-form button[type=submit]")
        refused(page)
        assert page.locator("input[type=number][name=GAINR]").is_disabled()
        assert rest(default_rig, "/ports/0/params")["GAINR"] == 0x10000
        # The right one: the change works.
        page.fill("#token", default_rig.token)
        page.click("#token-form button[type=submit]")
        page.wait_for_selector("#param-form:not([disabled])")
        assert page.locator("#token-state").inner_text() == "token accepted"
        assert page.locator("#needs-token").is_hidden()
        assert page.locator("#capture-one").is_enabled()
        gain = page.locator("input[type=number][name=GAINR]")
        gain.fill("2")
        gain.press("Enter")
        page.wait_for_function(
            "() => document.querySelector('[data-effect-for=GAINR]').dataset.frame !== undefined"
        )
        assert page.locator("[data-error-for=GAINR]").inner_text() == ""
        assert rest(default_rig, "/ports/0/params")["GAINR"] == 0x20000
        assert page.evaluate("() => sessionStorage.length") == 1
        assert all(default_rig.token not in u for u in o.requests)
        SCREENSHOTS.mkdir(parents=True, exist_ok=True)
        page.wait_for_timeout(1500)
        page.screenshot(path=str(SCREENSHOTS / "browser-single.png"), full_page=True)
    finally:
        o.close()


@pytest.fixture(scope="module")
def quad_rig() -> Iterator[Any]:
    """The quad scenario on one common trigger at 5 Hz (port 0 the master), small windows.

    The trigger starts first: a port in snapshot mode without a trigger takes no frames.
    """
    for rig in rig_of("quad"):
        auth = {"Authorization": f"Bearer {rig.token}"}

        def patch(port: int, changes: dict[str, int], rig: Any = rig, auth: Any = auth) -> None:
            url = f"{rig.camera_url}/api/v1/ports/{port}/params"
            httpx.patch(url, json=changes, headers=auth, timeout=30).raise_for_status()

        for port in range(4):
            small_window(rig, port)
        patch(0, {"TRIG_MASTER": 0, "TRIG_PERIOD": 20_000_000})
        for port in range(4):
            patch(port, {"TRIG": 4, "TRIG_MASTER": 0})
        yield rig


def test_the_quad_overview_shows_four_views_of_one_trigger(browser, quad_rig):
    o = Opened(browser, quad_rig, token=quad_rig.token)
    try:
        page = o.page
        page.check("#quad")
        page.wait_for_function(
            "() => document.querySelectorAll('#quad-grid img[data-timestamp-ns]').length === 4",
            timeout=60_000,
        )
        page.wait_for_selector("#quad-sync[data-sync=true]", timeout=30_000)
        stamps = page.eval_on_selector_all(
            "#quad-grid img", "els => els.map(e => [e.dataset.port, e.dataset.timestampNs])"
        )
        assert [p for p, _ in stamps] == ["0", "1", "2", "3"]
        assert len({t for _, t in stamps}) == 1
        for port in range(4):
            assert (
                page.locator(f"#quad-grid img[data-port='{port}']").evaluate("e => e.naturalWidth")
                == 320 // 8
            )
        page.screenshot(path=str(SCREENSHOTS / "browser-quad.png"), full_page=True)
    finally:
        o.close()


def test_the_lepton_view_is_false_colour_with_a_celsius_scale(browser):
    for rig in rig_of("mixed"):
        small_window(rig, 0)  # the Bayer ports' full frames take seconds to simulate
        small_window(rig, 1)
        o = Opened(browser, rig, token=rig.token)
        try:
            page = o.page
            page.click("#ports button[data-port='2']")
            page.wait_for_function(
                "() => live.dataset.port === '2' && live.dataset.width === '160'", timeout=60_000
            )
            page.wait_for_selector("#thermal:not([hidden])")
            low = float(page.locator("#t-low").inner_text().split()[0])
            high = float(page.locator("#t-high").inner_text().split()[0])
            assert -20 < low < high < 60
            assert page.locator("[name=EXPOS]").count() == 0  # not a Lepton control
            page.wait_for_timeout(2000)
            page.screenshot(path=str(SCREENSHOTS / "browser-lepton.png"), full_page=True)
        finally:
            o.close()


def settles(check: Any, seconds: float = 5.0) -> bool:
    """Whether ``check()`` comes true within ``seconds`` (a change "now" is in effect
    from the next frame)."""
    deadline = time.monotonic() + seconds
    while not check():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def test_on_a_tablet_the_page_is_one_column_without_sideways_scrolling(browser, default_rig):
    # A 10-inch tablet held upright, with touch: the view above the controls, both the
    # screen's width, and a tapped control takes effect as a clicked one does.
    context = browser.new_context(
        viewport={"width": 820, "height": 1180}, has_touch=True, is_mobile=True
    )
    try:
        page = context.new_page()
        page.goto(default_rig.camera_url + "/")
        page.fill("#token", default_rig.token)
        page.tap("#token-form button[type=submit]")
        page.wait_for_selector("#live[data-frame]", timeout=60_000)
        page.wait_for_selector("[name=FLIPH]:not([disabled])", timeout=30_000)
        layout = page.evaluate(
            """() => {
                const r = (id) => document.getElementById(id).getBoundingClientRect();
                return {scroll: document.documentElement.scrollWidth, width: innerWidth,
                        view: r("single").toJSON(), controls: r("controls").toJSON()};
            }"""
        )
        assert layout["scroll"] <= layout["width"]
        view, controls = layout["view"], layout["controls"]
        assert view["bottom"] <= controls["top"]  # one column: the view first
        for box in (view, controls):
            assert box["width"] >= 0.9 * layout["width"] - 40
        before = rest(default_rig, "/ports/0/params")["FLIPH"]
        with page.expect_response(lambda r: r.request.method == "PATCH") as patched:
            page.tap("input[name=FLIPH]")
        assert patched.value.status == 200
        assert settles(lambda: rest(default_rig, "/ports/0/params")["FLIPH"] == 1 - before)
        with page.expect_response(lambda r: r.request.method == "PATCH"):
            page.tap("input[name=FLIPH]")  # back as it was, for the other tests
        assert settles(lambda: rest(default_rig, "/ports/0/params")["FLIPH"] == before)
    finally:
        context.close()
