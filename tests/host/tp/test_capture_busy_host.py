"""The quad set's trigger period from one timed fetch, and a camera that cannot keep up.

Without ``--trigger-period-ms`` one frame is fetched and timed first, and the period is
lengthened until the set's four frames, fetched one after another, fit in `FIT_PERIODS`
periods. A set whose frames still leave the camera's buffer before they are fetched, or a
camera that does not answer in time, is an error naming ``--trigger-period-ms`` (and
``--timeout`` for a late answer); nothing is taken again.
"""

from __future__ import annotations

import time

import pytest

from elphel_host.errors import DeviceTimeout, FrameGoneError, QuadCaptureError
from elphel_host.tp import capture
from elphel_host.tp.capture import FIT_PERIODS, fetch_period
from elphel_host.tp.layout import QuadLayout
from elphel_host.tp.trigger import TICKS_PER_MS

LOST = FrameGoneError("port 1: frame 101 is no longer in imgsrv's buffer")
LATE = DeviceTimeout("the camera at http://cam:2324/last/prev*89/save/bimg did not answer in time")
HALF_S = 500 * TICKS_PER_MS


class SlowCamera:
    """A camera whose frames take ``fetch_s`` to fetch; records what was fetched."""

    def __init__(self, fetch_s: float, newest: int = 40) -> None:
        self.fetch_s, self.newest = fetch_s, newest
        self.fetched: list[tuple[int, int | None]] = []

    def frame(self, port: int = 0) -> dict[str, int]:
        return {"port": port, "frame": self.newest, "timestamp_ns": 0}

    def capture(self, port: int = 0, *, frame: int | None = None) -> None:
        self.fetched.append((port, frame))
        time.sleep(self.fetch_s)


def test_the_fetch_period_fits_the_frames_in_its_periods() -> None:
    assert FIT_PERIODS == 32  # half of a 64-frame ring buffer
    assert fetch_period(4.0, 4) == 500 * TICKS_PER_MS  # 16 s over 32 periods
    assert fetch_period(7.0, 4) == 875 * TICKS_PER_MS
    assert fetch_period(7.0001, 4) == 876 * TICKS_PER_MS  # whole milliseconds, rounded up
    assert FIT_PERIODS * fetch_period(3.3, 4) / TICKS_PER_MS >= 4 * 3.3 * 1000


@pytest.mark.parametrize(("fetch_s", "longer"), [(0.05, False), (6.0, True)])
@pytest.mark.parametrize("newest", [False, True])
def test_the_period_is_chosen_from_one_timed_fetch(fetch_s: float, longer: bool, newest) -> None:
    camera = SlowCamera(fetch_s)
    said: list[str] = []
    period = capture._period_for_fetches(
        camera,
        (2, 0, 1, 3),
        HALF_S,
        said.append,
        newest=newest,
    )
    # the first port's next frame, once; its newest when frames do not come
    assert camera.fetched == [(2, 40 if newest else None)]
    if longer:
        assert period >= fetch_period(fetch_s, 4) > HALF_S
    else:
        assert period == HALF_S
    assert len(said) == 1 and f"trigger period {period / TICKS_PER_MS:g} ms" in said[0]
    assert ("longer than" in said[0]) is longer


def fail_with(error: Exception):
    def take_set(camera, before, layout, trigger, deadline, step):
        raise error

    return take_set


@pytest.mark.parametrize("period_given", [False, True])
def test_a_set_lost_from_the_buffer_names_the_period(monkeypatch, period_given) -> None:
    monkeypatch.setattr(capture, "_take_set", fail_with(LOST))
    with pytest.raises(QuadCaptureError) as e:
        capture._take_set_in_time(
            None, {}, QuadLayout(), (0, HALF_S), 60.0, lambda *a: None, (period_given, False)
        )
    message = str(e.value)
    assert "give a longer one (--trigger-period-ms 2000)" in message
    assert "--timeout" not in message
    assert ("given 500 ms" in message) is period_given


def test_a_late_camera_names_the_period_and_the_timeout(monkeypatch) -> None:
    monkeypatch.setattr(capture, "_take_set", fail_with(LATE))
    with pytest.raises(
        QuadCaptureError, match=r"--trigger-period-ms 2000\) or a longer --timeout than 45 s"
    ):
        capture._take_set_in_time(
            None, {}, QuadLayout(), (0, HALF_S), 45.0, lambda *a: None, (True, True)
        )
