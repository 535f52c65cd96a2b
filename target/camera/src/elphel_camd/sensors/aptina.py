"""Frame-parameter rules shared by the Aptina Bayer sensors (MT9P006, MT9F002).

Both read a window of an image area (photo-finish: strips of PF_HEIGHT rows stacked into
WOI_HEIGHT), take exposure in whole rows, analog colour gains, the same trigger modes and
trigger-period rules; each driver supplies its own sizes, row time and limits.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

from elphel_camd.errors import ParameterRangeError
from elphel_camd.params import TRIG_PERIOD_MIN_REPEAT, TRIG_SNAPSHOT, TRIG_VALUES, check_range

PF_COMPOSITE_MAX = 16384

# Colour gain parameters and the registers that hold them (same names on both sensors).
GAIN_REGISTERS = {
    "GAINR": "red_gain",
    "GAING": "green1_gain",
    "GAINGB": "green2_gain",
    "GAINB": "blue_gain",
}

WRITABLE = frozenset(
    {
        "WOI_LEFT",
        "WOI_TOP",
        "WOI_WIDTH",
        "WOI_HEIGHT",
        "FLIPH",
        "FLIPV",
        "EXPOS",
        "VEXPOS",
        *GAIN_REGISTERS,
        "TRIG",
        "TRIG_PERIOD",
        "TRIG_MASTER",
        "TRIG_DELAY",
        "TRIG_DECIMATE",
        "PF_HEIGHT",
        "FP1000SLIM",
        "FPSFLAGS",
    }
)


def default_state(*, width: int, height: int, gain: int) -> dict[str, int]:
    """The state after init: the whole image, 10 ms, equal gains, free-run, no limits."""
    state = dict.fromkeys(WRITABLE, 0)
    state.update(WOI_WIDTH=width, WOI_HEIGHT=height, EXPOS=10_000)
    state.update(dict.fromkeys(GAIN_REGISTERS, gain))
    return state


def sensor_height(state: Mapping[str, int]) -> int:
    """Rows the sensor reads per frame: the strip height in photo-finish, else the window."""
    return state["PF_HEIGHT"] or state["WOI_HEIGHT"]


def check_window_and_modes(
    s: Mapping[str, int],
    *,
    image_width: int,
    image_height: int,
    gains: Iterable[str],
    gain_min: int,
    gain_max: int,
) -> int:
    """Check window, photo-finish, flips, gains, TRIG and FPSFLAGS; return the sensor rows."""
    check_range("WOI_WIDTH", s["WOI_WIDTH"], 2, image_width, even=True)
    check_range("WOI_LEFT", s["WOI_LEFT"], 0, image_width - s["WOI_WIDTH"], even=True)
    pf = s["PF_HEIGHT"]
    if pf:
        check_range("PF_HEIGHT", pf, 2, image_height, even=True)
        check_range("WOI_HEIGHT", s["WOI_HEIGHT"], pf, PF_COMPOSITE_MAX)
        if s["WOI_HEIGHT"] % pf:
            raise ParameterRangeError(
                "WOI_HEIGHT", s["WOI_HEIGHT"], f"a multiple of PF_HEIGHT={pf} up to 16384"
            )
    else:
        check_range("WOI_HEIGHT", s["WOI_HEIGHT"], 2, image_height, even=True)
    height = sensor_height(s)
    check_range("WOI_TOP", s["WOI_TOP"], 0, image_height - height, even=True)
    for name in ("FLIPH", "FLIPV"):
        check_range(name, s[name], 0, 1)
    for name in gains:
        check_range(name, s[name], gain_min, gain_max)
    if s["TRIG"] not in TRIG_VALUES:
        raise ParameterRangeError("TRIG", s["TRIG"], "0 (free-run), 4 (snapshot), 20 (GRR)")
    check_range("FPSFLAGS", s["FPSFLAGS"], 0, 3)
    return height


def set_exposure_rows(
    s: dict[str, int], changed: frozenset[str], *, row_s: float, max_rows: int
) -> int:
    """Fill VEXPOS and EXPOS (rounded to whole rows) from whichever of them was changed."""
    if {"EXPOS", "VEXPOS"} <= changed:
        raise ParameterRangeError("VEXPOS", s["VEXPOS"], "either EXPOS or VEXPOS, not both")
    if "VEXPOS" in changed:
        rows = s["VEXPOS"]
        check_range("VEXPOS", rows, 1, max_rows)
    else:
        check_range("EXPOS", s["EXPOS"], 1, math.floor(max_rows * row_s * 1e6))
        rows = max(1, round(s["EXPOS"] / (row_s * 1e6)))
    s["VEXPOS"] = rows
    s["EXPOS"] = round(rows * row_s * 1e6)
    return rows


def check_trigger(s: Mapping[str, int], *, busy_s: float) -> bool:
    """Check TRIG_PERIOD / TRIG_DECIMATE against a sensor busy ``busy_s`` per frame.

    Returns whether the port is in snapshot mode.
    """
    period = s["TRIG_PERIOD"]
    if 1 < period < TRIG_PERIOD_MIN_REPEAT:
        raise ParameterRangeError("TRIG_PERIOD", period, "0 (stop), 1 (single), >= 256")
    check_range("TRIG_DECIMATE", s["TRIG_DECIMATE"], 0, 0xFFFF)
    snapshot = bool(s["TRIG"] & TRIG_SNAPSHOT)
    busy_10ns = math.ceil(busy_s * 1e8)
    repeating = period >= TRIG_PERIOD_MIN_REPEAT
    if snapshot and repeating and period * (s["TRIG_DECIMATE"] + 1) < busy_10ns:
        raise ParameterRangeError(
            "TRIG_PERIOD",
            period,
            f">= {busy_10ns} (x10 ns: exposure plus readout at this window), 0 or 1",
        )
    return snapshot


def trigger_fps1000(s: Mapping[str, int]) -> int:
    """Frame rate (fps x 1000) the common trigger gives this port in snapshot mode."""
    period = s["TRIG_PERIOD"]
    if period < TRIG_PERIOD_MIN_REPEAT:
        return 0
    return round(1e11 / (period * (s["TRIG_DECIMATE"] + 1)))
