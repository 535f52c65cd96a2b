"""Sony IMX219 (Raspberry Pi camera v2): its parameter rules and the project's I2C driver.

Facts: shared/reference/frame-paths.md section 2. The register table and the model's
identity are in `elphel_camd.sensors.imx219_registers`.

The rules are plain functions, so that a board which reaches the sensor through its
kernel driver's V4L2 controls maps the same parameters the same way:

- a line lasts ``line_length_pck`` pixel clocks at the pixel rate (`row_time_s`); the
  exposure is whole lines (`exposure_lines`, `lines_to_us`), 4 .. frame length - 4;
- the analogue gain code c gives 256 / (256 - c) (`analogue_gain`, `analogue_gain_code`),
  the digital gain is value / 256; a 16.16 gain is split into the largest analogue gain
  not above it and the digital rest (`split_gain`, `total_gain`);
- the flips change the Bayer order of the first pixel (`bayer_order`);
- binning (BIN_HOR, BIN_VERT: 1 or 2) halves the output size along its axis
  (`binned_size`) with the 2x2 mode of registers 0x0174/0x0175; a line keeps its
  duration, so a binned frame has half the lines and the exposure the same line time
  (`frame_lines`); the window is then a multiple of 4 along that axis, so that the
  binned frame keeps whole 2x2 Bayer cells.

The sensor has one gain for all colours: writing any of GAINR, GAING, GAINGB, GAINB sets
all four. It runs free (no trigger input): TRIG is 0.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import ClassVar

from elphel_camd.errors import I2CError, ParameterRangeError
from elphel_camd.i2c.bus import I2CBus
from elphel_camd.i2c.byte_registers import ByteRegisterIO
from elphel_camd.params import (
    EXPOSURE,
    FUNCTIONS,
    GAINS,
    LIMITFPS,
    WINDOW,
    check_range,
)
from elphel_camd.sensors.base import IMAGE_PARAMS, State
from elphel_camd.sensors.imx219_registers import (
    ACTIVE_HEIGHT,
    ACTIVE_WIDTH,
    ANALOGUE_GAIN_CODE_MAX,
    BAYER,
    BINNING_2X2,
    BINNING_NONE,
    BITS,
    CHIP_ID,
    DIGITAL_GAIN_MAX,
    DIGITAL_GAIN_ONE,
    I2C_ADDRESS,
    INIT_WRITES,
    LINE_LENGTH_PIXELS,
    MODE_STREAMING,
    MODEL,
    PIXEL_RATE_HZ,
    SENSOR_CODE,
    TABLE,
    register_bytes,
)
from elphel_camd.sensors.register_file import RegisterFileSensor
from elphel_camd.sensors.registers import FieldRule, FieldRules

# Exposure limits in lines (reference: min 4, max frame_length - 4).
EXPOSURE_LINES_MIN = 4
EXPOSURE_MARGIN_LINES = 4
FRAME_LINES_MAX = 0xFFFF
# Shortest vertical blanking: the mainline driver's minimum (not in the reference facts).
FRAME_BLANKING_MIN = 32
GAIN_MIN = 0x10000  # 1.0
GAIN_MAX = 0xFC000  # 15.75, the daemon's gain limit (the chip reaches 10.67 x 16)
GAIN_PARAMS = ("GAINR", "GAING", "GAINGB", "GAINB")
_BAYER_AFTER_FLIPS = {(0, 0): "RGGB", (1, 0): "GRBG", (0, 1): "GBRG", (1, 1): "BGGR"}

WRITABLE = frozenset(
    {
        *IMAGE_PARAMS,
        *GAIN_PARAMS,
        "BIN_HOR",
        "BIN_VERT",
        "FP1000SLIM",
        "FPSFLAGS",
    }
)

# Parameters that are register fields: the flips in the orientation register.
RULES = FieldRules(
    TABLE,
    [
        FieldRule(WINDOW, "FLIPH", "orientation.hflip"),
        FieldRule(WINDOW, "FLIPV", "orientation.vflip"),
    ],
)

# Frames before the target frame at which each function's writes are issued: exposure,
# frame length, window and flips reach the image two frames after the write, gains one
# (the delays libcamera's IMX219 helper declares; not in the reference facts).
AHEAD: dict[str, tuple[int, int]] = {fn: (2, 2) for fn in FUNCTIONS} | {GAINS: (1, 1)}


def row_time_s(
    *, line_length_pixels: int = LINE_LENGTH_PIXELS, pixel_rate_hz: float = PIXEL_RATE_HZ
) -> float:
    """Duration of one line: ``line_length_pixels`` clocks at ``pixel_rate_hz``."""
    return line_length_pixels / pixel_rate_hz


def exposure_lines(exposure_us: float, *, row_s: float) -> int:
    """Whole lines nearest to an exposure (at least `EXPOSURE_LINES_MIN`)."""
    return max(EXPOSURE_LINES_MIN, round(exposure_us / (row_s * 1e6)))


def lines_to_us(lines: int, *, row_s: float) -> int:
    """EXPOS (µs) of an exposure of whole lines, as the daemon reports it."""
    return round(lines * row_s * 1e6)


def analogue_gain(code: int) -> float:
    """Analogue gain of a code: 256 / (256 - code)."""
    if not 0 <= code <= ANALOGUE_GAIN_CODE_MAX:
        raise ValueError(f"analogue gain code {code}; allowed 0..{ANALOGUE_GAIN_CODE_MAX}")
    return 256 / (256 - code)


def analogue_gain_code(gain: float) -> int:
    """The largest analogue gain code whose gain does not exceed ``gain`` (>= 1.0)."""
    if gain < 1.0:
        raise ValueError(f"analogue gain {gain}; allowed >= 1.0")
    code = math.floor(256 - 256 / gain + 1e-9)
    return min(ANALOGUE_GAIN_CODE_MAX, code)


def digital_gain(value: int) -> float:
    """Digital gain of a register value: value / 256."""
    return value / DIGITAL_GAIN_ONE


def split_gain(gain_16_16: int) -> tuple[int, int]:
    """(analogue code, digital value) for a 16.16 gain: analogue first, digital the rest."""
    gain = gain_16_16 / 0x10000
    code = analogue_gain_code(gain)
    rest = round(gain / analogue_gain(code) * DIGITAL_GAIN_ONE)
    return code, min(DIGITAL_GAIN_MAX, max(DIGITAL_GAIN_ONE, rest))


def total_gain(code: int, digital_value: int) -> float:
    """Gain of an analogue code and a digital value together."""
    return analogue_gain(code) * digital_gain(digital_value)


def bayer_order(fliph: int, flipv: int) -> str:
    """Bayer order of the first output pixel with these flips (RGGB without)."""
    return _BAYER_AFTER_FLIPS[bool(fliph), bool(flipv)]


def binned_size(width: int, height: int, *, binning_h: int, binning_v: int) -> tuple[int, int]:
    """Output size of a crop of ``width`` x ``height`` with the binning modes (0x0174/5)."""
    return (width // 2 if binning_h else width, height // 2 if binning_v else height)


def binning_mode(factor: int) -> int:
    """The binning register's value for a BIN_HOR / BIN_VERT factor (1 or 2)."""
    return BINNING_2X2 if factor == 2 else BINNING_NONE


def output_size(state: Mapping[str, int]) -> tuple[int, int]:
    """The frame's size: the window divided by the binning."""
    return state["WOI_WIDTH"] // state["BIN_HOR"], state["WOI_HEIGHT"] // state["BIN_VERT"]


def frame_lines(state: Mapping[str, int], *, row_s: float | None = None) -> int:
    """frame_length_lines for a state.

    The output's lines plus the minimum blanking, stretched to the FP1000SLIM limit when
    FPSFLAGS bit 0 is set, and at least `EXPOSURE_MARGIN_LINES` longer than the exposure.
    """
    row = row_time_s() if row_s is None else row_s
    lines = output_size(state)[1] + FRAME_BLANKING_MIN
    if state["FPSFLAGS"] & 1 and state["FP1000SLIM"]:
        lines = max(lines, math.ceil(1000 / state["FP1000SLIM"] / row))
    return max(lines, state["VEXPOS"] + EXPOSURE_MARGIN_LINES)


def _check_binning(s: Mapping[str, int]) -> None:
    """BIN_* is 1 or 2; a binned axis's window is a multiple of 4 (whole 2x2 cells out)."""
    for factor, size in (("BIN_HOR", "WOI_WIDTH"), ("BIN_VERT", "WOI_HEIGHT")):
        check_range(factor, s[factor], 1, 2)
        if s[factor] == 2 and s[size] % 4:
            raise ParameterRangeError(
                size, s[size], f"a multiple of 4 while {factor}=2 (whole Bayer cells binned)"
            )


def _check_window(s: Mapping[str, int]) -> None:
    check_range("WOI_WIDTH", s["WOI_WIDTH"], 2, ACTIVE_WIDTH, even=True)
    check_range("WOI_HEIGHT", s["WOI_HEIGHT"], 2, ACTIVE_HEIGHT, even=True)
    _check_binning(s)
    check_range("WOI_LEFT", s["WOI_LEFT"], 0, ACTIVE_WIDTH - s["WOI_WIDTH"], even=True)
    check_range("WOI_TOP", s["WOI_TOP"], 0, ACTIVE_HEIGHT - s["WOI_HEIGHT"], even=True)
    for name in ("FLIPH", "FLIPV"):
        check_range(name, s[name], 0, 1)
    check_range("FPSFLAGS", s["FPSFLAGS"], 0, 3)
    if s["TRIG"]:
        raise ParameterRangeError("TRIG", s["TRIG"], "0 (the IMX219 has no trigger input)")


def _set_gains(s: dict[str, int], changed: frozenset[str]) -> None:
    """One gain for all colours: the changed colour gains must agree; all four take it."""
    names = [name for name in GAIN_PARAMS if name in changed]
    asked = {s[name] for name in names}
    if len(asked) > 1:
        values = ", ".join(f"{name}={s[name]}" for name in names)
        raise ParameterRangeError(
            names[-1], s[names[-1]], f"one gain for all colours on the IMX219 (asked {values})"
        )
    gain = asked.pop() if asked else s["GAING"]
    check_range("GAING", gain, GAIN_MIN, GAIN_MAX)
    s.update(dict.fromkeys(GAIN_PARAMS, gain))


def _set_exposure(s: dict[str, int], changed: frozenset[str], *, row_s: float) -> int:
    """Fill VEXPOS and EXPOS (whole lines) from whichever of them was changed."""
    longest = FRAME_LINES_MAX - EXPOSURE_MARGIN_LINES
    if {"EXPOS", "VEXPOS"} <= changed:
        raise ParameterRangeError("VEXPOS", s["VEXPOS"], "either EXPOS or VEXPOS, not both")
    if "VEXPOS" in changed:
        check_range("VEXPOS", s["VEXPOS"], EXPOSURE_LINES_MIN, longest)
        lines = s["VEXPOS"]
    else:
        check_range("EXPOS", s["EXPOS"], 1, lines_to_us(longest, row_s=row_s))
        lines = min(longest, exposure_lines(s["EXPOS"], row_s=row_s))
    s["VEXPOS"] = lines
    s["EXPOS"] = lines_to_us(lines, row_s=row_s)
    return lines


def _check_frame_rate(s: Mapping[str, int], *, row_s: float) -> None:
    """The FP1000SLIM limit must fit the frame length register; FPSFLAGS bit 1 holds it."""
    if s["FPSFLAGS"] & 1 and s["FP1000SLIM"]:
        lowest = math.ceil(1000 / (row_s * FRAME_LINES_MAX))
        check_range("FP1000SLIM", s["FP1000SLIM"], lowest, 0x7FFFFFFF)
    if s["FPSFLAGS"] & 2:
        free = {**s, "VEXPOS": 0}
        frame = frame_lines(free, row_s=row_s)
        if s["VEXPOS"] + EXPOSURE_MARGIN_LINES > frame:
            longest = lines_to_us(frame - EXPOSURE_MARGIN_LINES, row_s=row_s)
            raise ParameterRangeError(
                "EXPOS", s["EXPOS"], f"1..{longest} us while FPSFLAGS bit 1 keeps the frame rate"
            )


class IMX219(RegisterFileSensor):
    """Driver of the IMX219 on its byte registers at 16-bit addresses.

    For a sensor no kernel driver owns; with the kernel's imx219 driver bound, the
    parameters go through V4L2 controls instead (the rules above map them).
    """

    model = MODEL
    table = TABLE
    i2c_address = I2C_ADDRESS
    chip_id_register = "chip_id"
    chip_id = CHIP_ID
    sensor_code = SENSOR_CODE
    bayer = BAYER
    bits = BITS
    image_width = ACTIVE_WIDTH
    image_height = ACTIVE_HEIGHT
    gain_min = GAIN_MIN
    gain_max = GAIN_MAX
    exposure_rows_max = FRAME_LINES_MAX - EXPOSURE_MARGIN_LINES
    ahead: ClassVar[Mapping[str, tuple[int, int]]] = AHEAD
    writable = WRITABLE
    rules = RULES

    @classmethod
    def probe(cls, bus: I2CBus, *, bus_name: str) -> IMX219 | None:
        """Return a driver if an IMX219 answers at 0x10 with chip id 0x0219, else None."""
        io = cls.open_io(bus, bus_name=bus_name, retries=1)
        try:
            value = io.read_word(TABLE["chip_id"].address)
        except I2CError:
            return None
        return cls(io) if value == CHIP_ID else None

    @staticmethod
    def open_io(bus: I2CBus, *, bus_name: str, retries: int = 2) -> ByteRegisterIO:
        """Register access to the IMX219 on a bus, each register with its byte count."""
        sizes = {r.address: register_bytes(r) for r in TABLE}
        return ByteRegisterIO(bus, I2C_ADDRESS, sizes=sizes, bus_name=bus_name, retries=retries)

    def row_time_s(self) -> float:
        """Duration of one line in the driver's timing (3448 clocks at 182.4 MHz)."""
        return row_time_s()

    def init(self) -> None:
        """Read the shadows, set RAW10 without binning, and start streaming."""
        super().init()
        for name, value in INIT_WRITES:
            self.write_if_changed(name, value)
        self.write_if_changed("mode_select", MODE_STREAMING)

    def defaults(self) -> State:
        state = dict.fromkeys(
            [*WRITABLE, "TRIG", "TRIG_PERIOD", "TRIG_MASTER", "TRIG_DELAY", "TRIG_DECIMATE"], 0
        )
        state.update(WOI_WIDTH=ACTIVE_WIDTH, WOI_HEIGHT=ACTIVE_HEIGHT, EXPOS=10_000)
        state.update(dict.fromkeys(GAIN_PARAMS, GAIN_MIN), PF_HEIGHT=0, BIN_HOR=1, BIN_VERT=1)
        return self.normalize(state, frozenset({"EXPOS"}))

    def normalize(self, state: Mapping[str, int], changed: frozenset[str]) -> State:
        s = dict(state)
        _check_window(s)
        _set_gains(s, changed)
        row_s = self.row_time_s()
        _set_exposure(s, changed, row_s=row_s)
        _check_frame_rate(s, row_s=row_s)
        s["FP1000S"] = round(1000 / self.frame_period_s(s))
        s["SENSOR"] = self.sensor_code
        s["COLOR"] = 15
        s["BITS"] = 16
        return s

    def frame_period_s(self, state: Mapping[str, int]) -> float:
        row_s = self.row_time_s()
        return frame_lines(state, row_s=row_s) * row_s

    def actual_gains(self, state: Mapping[str, int]) -> dict[str, int]:
        """16.16 gains the analogue code and digital value really give."""
        gain = round(total_gain(*split_gain(state["GAING"])) * 0x10000)
        return dict.fromkeys(GAIN_PARAMS, gain)

    def registers(self, function: str, state: Mapping[str, int]) -> dict[str, int]:
        values: dict[str, int] = {}
        if function == WINDOW:
            left, top = state["WOI_LEFT"], state["WOI_TOP"]
            width, height = state["WOI_WIDTH"], state["WOI_HEIGHT"]
            out_width, out_height = output_size(state)
            values = {
                "x_addr_start": left,
                "x_addr_end": left + width - 1,
                "y_addr_start": top,
                "y_addr_end": top + height - 1,
                "x_output_size": out_width,
                "y_output_size": out_height,
                "binning_mode_h": binning_mode(state["BIN_HOR"]),
                "binning_mode_v": binning_mode(state["BIN_VERT"]),
            }
        elif function == LIMITFPS:
            values = {"frame_length_lines": frame_lines(state, row_s=self.row_time_s())}
        elif function == EXPOSURE:
            values = {"coarse_integration_time": state["VEXPOS"]}
        elif function == GAINS:
            code, digital = split_gain(state["GAING"])
            values = {"analogue_gain": code, "digital_gain": digital}
        values.update(RULES.registers(function, state, self.shadow))
        return values
