"""What the Aptina Bayer sensors (MT9P006, MT9F002) share: `AptinaSensor` and its rules.

Both read a window of an image area (photo-finish: strips of PF_HEIGHT rows stacked into
WOI_HEIGHT), take exposure in whole rows, analog colour gains, the same trigger modes and
trigger-period rules; each model supplies its sizes, row time, gain code, limits, the
registers its window, exposure and frame-rate limit need, and its parameter -> field
rules (flips, trigger mode) as data.
"""

from __future__ import annotations

import math
from abc import abstractmethod
from collections.abc import Iterable, Mapping
from typing import ClassVar, NoReturn

from elphel_camd.errors import ParameterRangeError
from elphel_camd.params import (
    EXPOSURE,
    GAINS,
    LIMITFPS,
    TRIG_PERIOD_MIN_REPEAT,
    TRIG_SNAPSHOT,
    TRIG_VALUES,
    TRIGGERMODE,
    TRIGSEQ,
    WINDOW,
    check_range,
)
from elphel_camd.sensors.base import IMAGE_PARAMS, State
from elphel_camd.sensors.register_file import RegisterFileSensor
from elphel_camd.sensors.registers import FieldRules

PF_COMPOSITE_MAX = 16384
TRIG_GRR = 0x10  # the global-reset-release bit of TRIG (20 = snapshot 4 | GRR 16)
# Rows a triggered sensor needs after exposure and readout before the next trigger
# (Elphel's minimum vertical blanking).
READY_BLANK_ROWS = 9

# Colour gain parameters and the registers that hold them (same names on both sensors).
GAIN_REGISTERS = {
    "GAINR": "red_gain",
    "GAING": "green1_gain",
    "GAINGB": "green2_gain",
    "GAINB": "blue_gain",
}

WRITABLE = frozenset(
    {
        *IMAGE_PARAMS,
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


def rows_to_us(rows: int, *, row_s: float) -> int:
    """EXPOS (µs) of an exposure of ``rows`` whole rows, as the daemon reports it."""
    return round(rows * row_s * 1e6)


def exposure_max_us(*, row_s: float, max_rows: int) -> int:
    """The longest EXPOS at this row time: ``max_rows`` whole rows, as reported.

    It is the value the daemon reports for that exposure, so writing it back is
    accepted as it is (a limit rounded down instead would leave the longest exposure
    reported one µs above the limit, and refused the next time the state is checked).
    """
    return rows_to_us(max_rows, row_s=row_s)


def set_exposure_rows(
    s: dict[str, int], changed: frozenset[str], *, row_s: float, max_rows: int
) -> int:
    """Fill VEXPOS and EXPOS (rounded to whole rows) from whichever of them was changed.

    Any EXPOS up to `exposure_max_us` rounds to at most ``max_rows`` rows, and the
    EXPOS reported for them is again within that limit.
    """
    if {"EXPOS", "VEXPOS"} <= changed:
        raise ParameterRangeError("VEXPOS", s["VEXPOS"], "either EXPOS or VEXPOS, not both")
    if "VEXPOS" in changed:
        rows = s["VEXPOS"]
        check_range("VEXPOS", rows, 1, max_rows)
    else:
        check_range("EXPOS", s["EXPOS"], 1, exposure_max_us(row_s=row_s, max_rows=max_rows))
        rows = min(max_rows, max(1, round(s["EXPOS"] / (row_s * 1e6))))
    s["VEXPOS"] = rows
    s["EXPOS"] = rows_to_us(rows, row_s=row_s)
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


def elphel_ahead(*, frame_snapshot: int) -> dict[str, tuple[int, int]]:
    """Elphel's ahead table of an Aptina sensor: (free-run, snapshot) frames per function.

    The continuous and async SKIP=0 columns of Elphel's tables: trigger mode and trigger
    sequencer 2 / 1, gains 1 / 1; window, frame-rate limit and exposure 2 in free-run and
    ``frame_snapshot`` in snapshot mode (1 on the MT9P006, 2 on the MT9F002).
    """
    frame = (2, frame_snapshot)
    return {
        TRIGGERMODE: (2, 1),
        WINDOW: frame,
        GAINS: (1, 1),
        LIMITFPS: frame,
        EXPOSURE: frame,
        TRIGSEQ: (2, 1),
    }


def busy_s(*, rows: int, height: int, row_s: float) -> float:
    """Shortest trigger-to-ready time: exposure, readout and the minimum blanking."""
    return (rows + height + READY_BLANK_ROWS) * row_s


def unreachable_fps_limit(s: Mapping[str, int], *, row_s: float, max_rows: int) -> NoReturn:
    """Raise for an FP1000SLIM that needs a frame longer than ``max_rows`` rows."""
    lowest = math.ceil(1000 / (row_s * max_rows))
    raise ParameterRangeError(
        "FP1000SLIM", s["FP1000SLIM"], f">= {lowest} at this window (or FPSFLAGS bit 0 off)"
    )


def check_keep_fps(s: Mapping[str, int], *, rows: int, frame_rows: int, row_s: float) -> None:
    """With FPSFLAGS bit 1 the exposure may not lengthen a frame of ``frame_rows`` rows."""
    if s["FPSFLAGS"] & 2 and rows >= frame_rows:
        longest = round((frame_rows - 1) * row_s * 1e6)
        raise ParameterRangeError(
            "EXPOS", s["EXPOS"], f"1..{longest} us while FPSFLAGS bit 1 keeps the frame rate"
        )


class AptinaSensor(RegisterFileSensor):
    """The parameter model and register programming the Aptina drivers share.

    A model sets its geometry and limits, its ``rules`` (parameter -> field, as data),
    ``fixed`` register values, its init list, and implements the gain code, the row time,
    its frame-timing checks and the registers computed from a state
    (`computed_registers`). `registers` puts them together in a fixed order: computed
    registers, then the gains, then the registers the field rules compose, then the
    fixed values.
    """

    image_width: ClassVar[int]
    image_height: ClassVar[int]
    gain_min: ClassVar[int]
    gain_max: ClassVar[int]
    default_gain: ClassVar[int]
    exposure_rows_max: ClassVar[int]
    rules: ClassVar[FieldRules]
    # Register values a program function always writes (e.g. no skipping, no binning).
    fixed: ClassVar[Mapping[str, Mapping[str, int]]] = {}
    # Elphel's init list, written after the shadows are read: every entry whatever the
    # chip holds if ``init_rewrites``, else only those that differ from the shadow.
    init_writes: ClassVar[tuple[tuple[str, int], ...]] = ()
    init_rewrites: ClassVar[bool] = False
    writable = WRITABLE

    @staticmethod
    @abstractmethod
    def encode_gain(gain_16_16: int) -> int:
        """Colour-gain register code for a 16.16 gain."""

    @staticmethod
    @abstractmethod
    def decode_gain(code: int) -> float:
        """Total gain of a colour-gain register code."""

    @staticmethod
    @abstractmethod
    def row_time_s(width: int) -> float:
        """Duration of one row at a window width."""

    @abstractmethod
    def check_timing(self, s: State, *, height: int, rows: int, row_s: float) -> bool:
        """Check frame-rate limit, keep-fps flag and trigger; return whether in snapshot."""

    @abstractmethod
    def computed_registers(self, function: str, state: Mapping[str, int]) -> dict[str, int]:
        """Register values computed from a state (window, exposure, blanking)."""

    def init(self) -> None:
        super().init()
        for name, value in self.init_writes:
            if self.init_rewrites:
                self.write(name, value)
            else:
                self.write_if_changed(name, value)

    def defaults(self) -> State:
        state = default_state(
            width=self.image_width, height=self.image_height, gain=self.default_gain
        )
        return self.normalize(state, frozenset({"EXPOS"}))

    def normalize(self, state: Mapping[str, int], changed: frozenset[str]) -> State:
        s = dict(state)
        height = check_window_and_modes(
            s,
            image_width=self.image_width,
            image_height=self.image_height,
            gains=GAIN_REGISTERS,
            gain_min=self.gain_min,
            gain_max=self.gain_max,
        )
        row_s = self.row_time_s(s["WOI_WIDTH"])
        rows = set_exposure_rows(s, changed, row_s=row_s, max_rows=self.exposure_rows_max)
        if self.check_timing(s, height=height, rows=rows, row_s=row_s):
            s["FP1000S"] = trigger_fps1000(s)
        else:
            s["FP1000S"] = round(1000 / self.frame_period_s(s))
        s["SENSOR"] = self.sensor_code
        s["COLOR"] = 15
        s["BITS"] = 16
        return s

    def registers(self, function: str, state: Mapping[str, int]) -> dict[str, int]:
        values = self.computed_registers(function, state)
        if function == GAINS:
            values.update(
                {reg: self.encode_gain(state[name]) for name, reg in GAIN_REGISTERS.items()}
            )
        values.update(self.rules.registers(function, state, self.shadow))
        values.update(self.fixed.get(function, {}))
        return values

    def actual_gains(self, state: Mapping[str, int]) -> dict[str, int]:
        """16.16 gains the register codes really give (the request minus its residual)."""
        return {
            name: round(self.decode_gain(self.encode_gain(state[name])) * 0x10000)
            for name in GAIN_REGISTERS
        }
