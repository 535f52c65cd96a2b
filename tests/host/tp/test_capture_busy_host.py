"""A quad set whose frames left the camera's buffer before they were fetched, or whose
camera did not answer in time (a busy host).

Without ``--trigger-period-ms`` the set is taken again at a slower trigger; with it, or
when that fails too, the error names the option and a period to give.
"""

from __future__ import annotations

import time

import pytest

from elphel_host.errors import DeviceTimeout, FrameGoneError, QuadCaptureError
from elphel_host.tp import capture
from elphel_host.tp.layout import QuadLayout
from elphel_host.tp.trigger import TICKS_PER_MS

LOST = FrameGoneError("port 1: frame 101 is no longer in imgsrv's buffer")
LATE = DeviceTimeout("the camera at http://cam:2324/last/prev*89/save/bimg did not answer in time")


@pytest.fixture(params=[LOST, LATE], ids=["frame-gone", "camera-late"])
def error(request):
    return request.param


def fake_take_set(fails: int, periods: list[int], error: Exception, waits: list[float]):
    def take_set(camera, before, layout, trigger, deadline, step):
        periods.append(trigger[1])
        waits.append(deadline - time.monotonic())
        if len(periods) <= fails:
            raise error
        return {"set": trigger[1]}

    return take_set


def take(monkeypatch, fails: int, fixed: float | None, error: Exception = LOST, waits=None):
    periods: list[int] = []
    waits = [] if waits is None else waits
    monkeypatch.setattr(capture, "_take_set", fake_take_set(fails, periods, error, waits))
    period = round(500 * TICKS_PER_MS)
    got = capture._take_set_patiently(
        None, {}, QuadLayout(), (0, period), 60.0, lambda *a: None, fixed=fixed
    )
    return got, periods


def test_default_period_is_slowed_once(monkeypatch, error) -> None:
    waits: list[float] = []
    (taken, period), periods = take(monkeypatch, fails=1, fixed=None, error=error, waits=waits)
    # the retake waits as many periods as the first attempt: four times as long
    assert 59 < waits[0] <= 60 and 239 < waits[1] <= 240
    assert periods == [50_000_000, 200_000_000] and period == 200_000_000
    assert taken == {"set": 200_000_000}


@pytest.mark.parametrize(("fails", "fixed"), [(2, None), (1, 500.0)])
def test_the_error_names_the_option(monkeypatch, fails, fixed, error) -> None:
    with pytest.raises(QuadCaptureError, match=r"give a longer one \(--trigger-period-ms \d+\)"):
        take(monkeypatch, fails=fails, fixed=fixed, error=error)
