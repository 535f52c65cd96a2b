"""MT9P006 / MT9P031 (5 MPix): register table and identity.

Facts: shared/reference/sensors.md section 1 (addresses and reset values from the
datasheet, the Linux kernel driver and Elphel's driver, paraphrased).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import ClassVar

from elphel_camd.errors import ParameterRangeError
from elphel_camd.params import (
    EXPOSURE,
    GAINS,
    LIMITFPS,
    TRIG_SNAPSHOT,
    TRIGGERMODE,
    TRIGSEQ,
    WINDOW,
)
from elphel_camd.sensors.aptina import (
    GAIN_REGISTERS,
    WRITABLE,
    check_trigger,
    check_window_and_modes,
    default_state,
    sensor_height,
    set_exposure_rows,
    trigger_fps1000,
)
from elphel_camd.sensors.base import SensorDriver, State
from elphel_camd.sensors.registers import Access, Register, RegisterTable

MODEL = "MT9P006"
I2C_ADDRESS = 0x48
CHIP_ID = 0x1801
CHIP_ID_MASK = 0xFF00  # Elphel compares the family byte only
SENSOR_CODE = 0x34  # Elphel's SENSOR_MT9P006 code, reported as the SENSOR parameter
BAYER = "GRBG"  # first pixel of the default window
PIXEL_PITCH_UM = 2.2
ACTIVE_WIDTH = 2592
ACTIVE_HEIGHT = 1944
ARRAY_WIDTH = 2752
ARRAY_HEIGHT = 2004
CLEAR_LEFT = 10  # Elphel's first clear column / row of the array
CLEAR_TOP = 50
BITS = 12
SENSOR_CLOCK_HZ = 96_000_000

TABLE = RegisterTable(
    MODEL,
    [
        Register("chip_version", 0x00, CHIP_ID, Access.RO, doc="chip version, 0x1801"),
        Register(
            "row_start",
            0x01,
            54,
            minimum=0,
            maximum=2004,
            unit="rows",
            doc="first row of the window; even",
        ),
        Register(
            "column_start",
            0x02,
            16,
            minimum=0,
            maximum=2750,
            unit="columns",
            doc="first column of the window; even",
        ),
        Register(
            "row_size",
            0x03,
            1943,
            minimum=1,
            maximum=2005,
            unit="rows",
            doc="window height minus one (odd)",
        ),
        Register(
            "column_size",
            0x04,
            2591,
            minimum=1,
            maximum=2751,
            unit="columns",
            doc="window width minus one (odd)",
        ),
        Register(
            "horizontal_blank", 0x05, 0, maximum=4095, unit="pixclk", doc="horizontal blanking"
        ),
        Register("vertical_blank", 0x06, 0x19, maximum=4095, unit="rows", doc="vertical blanking"),
        Register("output_control", 0x07, 0x1F82, doc="bit 0 hold updates, bit 1 chip enable"),
        Register(
            "shutter_width_upper",
            0x08,
            0,
            maximum=0xF,
            width=16,
            unit="rows",
            doc="bits 19:16 of the shutter width",
        ),
        Register(
            "shutter_width_lower", 0x09, 0x0797, unit="rows", doc="bits 15:0 of the shutter width"
        ),
        Register("pixel_clock_control", 0x0A, 0, doc="divide, shift, invert"),
        Register("restart", 0x0B, 0, doc="bit 0 restart, bit 1 pause, bit 2 software trigger"),
        Register("shutter_delay", 0x0C, 0, maximum=0x1FFF, doc="sub-row integration reduction"),
        Register("reset", 0x0D, 0, maximum=1, doc="1 = soft reset asserted"),
        Register("pll_control", 0x10, 0x0050, doc="bit 0 power PLL, bit 1 use PLL"),
        Register("pll_config_1", 0x11, 0x6404, doc="M (15:8), N-1 (5:0)"),
        Register("pll_config_2", 0x12, 0, maximum=0x1F, doc="P1-1"),
        Register(
            "read_mode_1",
            0x1E,
            0x4006,
            doc="bit 7 global reset release, bit 8 snapshot, bit 9 invert trigger",
        ),
        Register(
            "read_mode_2",
            0x20,
            0x0040,
            doc="bit 14 column mirror (FLIPH), bit 15 row mirror (FLIPV)",
        ),
        Register("row_address_mode", 0x22, 0, maximum=0x37, doc="row skip (2:0), row bin (5:4)"),
        Register(
            "column_address_mode", 0x23, 0, maximum=0x37, doc="column skip (2:0), column bin (5:4)"
        ),
        Register(
            "green1_gain",
            0x2B,
            0x0008,
            maximum=0x7F7F,
            doc="analog gain (5:0)/8, x2 stage (6), digital (14:8)",
        ),
        Register("blue_gain", 0x2C, 0x0008, maximum=0x7F7F, doc="as green1_gain"),
        Register("red_gain", 0x2D, 0x0008, maximum=0x7F7F, doc="as green1_gain"),
        Register("green2_gain", 0x2E, 0x0008, maximum=0x7F7F, doc="as green1_gain"),
        Register("global_gain", 0x35, 0x0008, maximum=0x7F7F, doc="writes all four colour gains"),
        Register("row_black_target", 0x49, 0xA8, maximum=0xFFF, doc="row black target"),
        Register("row_black_default_offset", 0x4B, 0x28, maximum=0xFFF, doc="black offset"),
        Register("blc_control", 0x62, 0, doc="bit 0 manual black level"),
        Register("reserved_7f", 0x7F, 0, doc="written 0 at init against blue blooming columns"),
        Register("test_pattern", 0xA0, 0, doc="bit 0 enable, bits 6:3 mode"),
    ],
    address_bytes=1,
)


# A row lasts width + 2 * HORIZONTAL_BLANK pixel clocks; 450 is Elphel's minimum without
# binning (reference 1.4). Vertical blanking is at least 9 rows.
HORIZONTAL_BLANK = 450
VERTICAL_BLANK_MIN = 9
VERTICAL_BLANK_MAX = 2047
SHUTTER_MAX = 0xFFFFF
GAIN_MIN = 0x10000  # 1.0
GAIN_MAX = 0xFC000  # 15.75, the largest analog code (x2 stage, 63/8)


def row_time_s(width: int, *, horizontal_blank: int = HORIZONTAL_BLANK) -> float:
    """Duration of one row at a window width (Elphel's timing model)."""
    return (width + 2 * horizontal_blank) / SENSOR_CLOCK_HZ


def decode_gain(code: int) -> float:
    """Total gain of a colour-gain register: (1 + digital/8) * (1 + x2 stage) * analog/8."""
    analog = code & 0x3F
    doubler = (code >> 6) & 1
    digital = (code >> 8) & 0x7F
    return (1 + digital / 8) * (1 + doubler) * analog / 8


def encode_gain(gain_16_16: int) -> int:
    """Analog-only gain code for a 16.16 gain, as Elphel programs it.

    Up to 3.94x the x2 stage stays off and the analog field is gain*8; above it the x2
    stage is on and the field is gain*4. The difference to the request is the residual.
    """
    gain = gain_16_16 / 0x10000
    if gain <= 3.94:
        return min(63, round(gain * 8))
    return 0x40 | min(63, round(gain * 4))


def vertical_blank(state: Mapping[str, int]) -> int:
    """Rows of vertical blanking: the minimum, or more to hold the FP1000SLIM limit."""
    blank = VERTICAL_BLANK_MIN
    limit = state["FP1000SLIM"]
    if state["FPSFLAGS"] & 1 and limit:
        row_s = row_time_s(state["WOI_WIDTH"])
        blank = max(blank, math.ceil(1000 / limit / row_s) - sensor_height(state))
    return blank


class MT9P006(SensorDriver):
    """Driver of the MT9P006 / MT9P031 on its 8-bit-address register map."""

    model = MODEL
    table = TABLE
    i2c_address = I2C_ADDRESS
    chip_id_register = "chip_version"
    chip_id = CHIP_ID
    chip_id_mask = CHIP_ID_MASK
    sensor_code = SENSOR_CODE
    bayer = BAYER
    bits = BITS
    # Elphel's mt9x001 ahead table (continuous SKIP=0, async SKIP=0 columns).
    ahead: ClassVar[Mapping[str, tuple[int, int]]] = {
        TRIGGERMODE: (2, 1),
        WINDOW: (2, 1),
        GAINS: (1, 1),
        LIMITFPS: (2, 1),
        EXPOSURE: (2, 1),
        TRIGSEQ: (2, 1),
    }
    writable = WRITABLE

    def init(self) -> None:
        super().init()
        self.write_if_changed("output_control", 0x1F82)
        self.write_if_changed("reserved_7f", 0)  # against blue blooming columns

    def defaults(self) -> State:
        state = default_state(width=ACTIVE_WIDTH, height=ACTIVE_HEIGHT, gain=0x10000)
        return self.normalize(state, frozenset({"EXPOS"}))

    def normalize(self, state: Mapping[str, int], changed: frozenset[str]) -> State:
        s = dict(state)
        height = check_window_and_modes(
            s,
            image_width=ACTIVE_WIDTH,
            image_height=ACTIVE_HEIGHT,
            gains=GAIN_REGISTERS,
            gain_min=GAIN_MIN,
            gain_max=GAIN_MAX,
        )
        row_s = row_time_s(s["WOI_WIDTH"])
        rows = set_exposure_rows(s, changed, row_s=row_s, max_rows=SHUTTER_MAX)
        blank = vertical_blank(s)
        if blank > VERTICAL_BLANK_MAX:
            lowest = math.ceil(1000 / (row_s * (height + VERTICAL_BLANK_MAX)))
            raise ParameterRangeError(
                "FP1000SLIM", s["FP1000SLIM"], f">= {lowest} at this window (or FPSFLAGS bit 0 off)"
            )
        if s["FPSFLAGS"] & 2 and rows >= height + blank:
            longest = round((height + blank - 1) * row_s * 1e6)
            raise ParameterRangeError(
                "EXPOS", s["EXPOS"], f"1..{longest} us while FPSFLAGS bit 1 keeps the frame rate"
            )
        busy_s = (rows + height + VERTICAL_BLANK_MIN) * row_s
        if check_trigger(s, busy_s=busy_s):
            s["FP1000S"] = trigger_fps1000(s)
        else:
            s["FP1000S"] = round(1000 / self.frame_period_s(s))
        s["SENSOR"] = SENSOR_CODE
        s["COLOR"] = 15
        s["BITS"] = 16
        return s

    def frame_period_s(self, state: Mapping[str, int]) -> float:
        rows = max(sensor_height(state) + vertical_blank(state), state["VEXPOS"] + 1)
        return rows * row_time_s(state["WOI_WIDTH"])

    def registers(self, function: str, state: Mapping[str, int]) -> dict[str, int]:
        if function == WINDOW:
            flips = (state["FLIPH"] << 14) | (state["FLIPV"] << 15)
            read_mode_2 = (self.shadow.get("read_mode_2", 0x0040) & 0x3FFF) | flips
            return {
                "row_start": CLEAR_TOP + state["WOI_TOP"],
                "column_start": CLEAR_LEFT + state["WOI_LEFT"],
                "row_size": sensor_height(state) - 1,
                "column_size": state["WOI_WIDTH"] - 1,
                "read_mode_2": read_mode_2,
                "row_address_mode": 0,
                "column_address_mode": 0,
            }
        if function == EXPOSURE:
            rows = state["VEXPOS"]
            return {"shutter_width_upper": rows >> 16, "shutter_width_lower": rows & 0xFFFF}
        if function == GAINS:
            return {reg: encode_gain(state[name]) for name, reg in GAIN_REGISTERS.items()}
        if function == TRIGGERMODE:
            mode = self.shadow.get("read_mode_1", 0x4006) & ~0x0180
            if state["TRIG"] & TRIG_SNAPSHOT:
                mode |= 0x0100
            if state["TRIG"] & 0x10:
                mode |= 0x0080
            return {"read_mode_1": mode}
        if function == LIMITFPS:
            return {"horizontal_blank": HORIZONTAL_BLANK, "vertical_blank": vertical_blank(state)}
        return {}

    def actual_gains(self, state: Mapping[str, int]) -> dict[str, int]:
        """16.16 gains the register codes really give (the request minus its residual)."""
        return {
            name: round(decode_gain(encode_gain(state[name])) * 0x10000) for name in GAIN_REGISTERS
        }
