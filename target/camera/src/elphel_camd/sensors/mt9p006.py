"""MT9P006 / MT9P031 (5 MPix): gain code, timing and the driver.

Facts: shared/reference/sensors.md section 1. The register table, its bit fields and the
model's identity are in `elphel_camd.sensors.mt9p006_registers`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import ClassVar

from elphel_camd.params import (
    EXPOSURE,
    LIMITFPS,
    TRIG_SNAPSHOT,
    TRIGGERMODE,
    WINDOW,
)
from elphel_camd.sensors import aptina
from elphel_camd.sensors.base import State
from elphel_camd.sensors.mt9p006_registers import (
    ACTIVE_HEIGHT,
    ACTIVE_WIDTH,
    ARRAY_HEIGHT,
    ARRAY_WIDTH,
    BAYER,
    BITS,
    CHIP_ID,
    CHIP_ID_MASK,
    CLEAR_LEFT,
    CLEAR_TOP,
    I2C_ADDRESS,
    INIT_WRITES,
    MODEL,
    PIXEL_PITCH_UM,
    SENSOR_CLOCK_HZ,
    SENSOR_CODE,
    TABLE,
)
from elphel_camd.sensors.registers import FieldRule, FieldRules

__all__ = [
    "ACTIVE_HEIGHT",
    "ACTIVE_WIDTH",
    "ARRAY_HEIGHT",
    "ARRAY_WIDTH",
    "BAYER",
    "CLEAR_LEFT",
    "CLEAR_TOP",
    "MODEL",
    "MT9P006",
    "PIXEL_PITCH_UM",
    "RULES",
    "SENSOR_CLOCK_HZ",
    "TABLE",
    "decode_gain",
    "encode_gain",
    "row_time_s",
]

# A row lasts width + 2 * HORIZONTAL_BLANK pixel clocks; 450 is Elphel's minimum without
# binning (reference 1.4). Vertical blanking is at least 9 rows.
HORIZONTAL_BLANK = 450
VERTICAL_BLANK_MIN = 9
VERTICAL_BLANK_MAX = 2047
SHUTTER_MAX = 0xFFFFF
GAIN_MIN = 0x10000  # 1.0
GAIN_MAX = 0xFC000  # 15.75, the largest analog code (x2 stage, 63/8)

# Parameters that are register fields (reference 1.4, 1.5): flips in read mode 2, the
# trigger mode in read mode 1.
RULES = FieldRules(
    TABLE,
    [
        FieldRule(WINDOW, "FLIPH", "read_mode_2.mirror_column"),
        FieldRule(WINDOW, "FLIPV", "read_mode_2.mirror_row"),
        FieldRule(TRIGGERMODE, "TRIG", "read_mode_1.snapshot", mask=TRIG_SNAPSHOT),
        FieldRule(TRIGGERMODE, "TRIG", "read_mode_1.global_reset", mask=aptina.TRIG_GRR),
    ],
)


def row_time_s(width: int, *, horizontal_blank: int = HORIZONTAL_BLANK) -> float:
    """Duration of one row at a window width (Elphel's timing model)."""
    return (width + 2 * horizontal_blank) / SENSOR_CLOCK_HZ


_ANALOG = TABLE.field("green1_gain.analog")  # every colour gain has this layout
_X2 = TABLE.field("green1_gain.x2")
_DIGITAL = TABLE.field("green1_gain.digital")


def decode_gain(code: int) -> float:
    """Total gain of a colour-gain register: (1 + digital/8) * (1 + x2 stage) * analog/8."""
    digital = _DIGITAL.get(code)
    return (1 + digital / 8) * (1 + _X2.get(code)) * _ANALOG.get(code) / 8


def encode_gain(gain_16_16: int) -> int:
    """Analog-only gain code for a 16.16 gain, as Elphel programs it.

    Up to 3.94x the x2 stage stays off and the analog field is gain*8; above it the x2
    stage is on and the field is gain*4. The difference to the request is the residual.
    """
    gain = gain_16_16 / 0x10000
    top = _ANALOG.field.limit
    if gain <= 3.94:
        return _ANALOG.put(0, min(top, round(gain * 8)))
    return _X2.put(_ANALOG.put(0, min(top, round(gain * 4))), 1)


def vertical_blank(state: Mapping[str, int]) -> int:
    """Rows of vertical blanking: the minimum, or more to hold the FP1000SLIM limit."""
    blank = VERTICAL_BLANK_MIN
    limit = state["FP1000SLIM"]
    if state["FPSFLAGS"] & 1 and limit:
        row_s = row_time_s(state["WOI_WIDTH"])
        blank = max(blank, math.ceil(1000 / limit / row_s) - aptina.sensor_height(state))
    return blank


class MT9P006(aptina.AptinaSensor):
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
    image_width = ACTIVE_WIDTH
    image_height = ACTIVE_HEIGHT
    gain_min = GAIN_MIN
    gain_max = GAIN_MAX
    default_gain = 0x10000
    exposure_rows_max = SHUTTER_MAX
    # Elphel's mt9x001 ahead table.
    ahead: ClassVar[Mapping[str, tuple[int, int]]] = aptina.elphel_ahead(frame_snapshot=1)
    rules = RULES
    # No skipping, no binning (Elphel's DCM and BIN 1).
    fixed: ClassVar[Mapping[str, Mapping[str, int]]] = {
        WINDOW: {"row_address_mode": 0, "column_address_mode": 0}
    }
    init_writes = INIT_WRITES
    encode_gain = staticmethod(encode_gain)
    decode_gain = staticmethod(decode_gain)
    row_time_s = staticmethod(row_time_s)

    def check_timing(self, s: State, *, height: int, rows: int, row_s: float) -> bool:
        blank = vertical_blank(s)
        if blank > VERTICAL_BLANK_MAX:
            aptina.unreachable_fps_limit(s, row_s=row_s, max_rows=height + VERTICAL_BLANK_MAX)
        aptina.check_keep_fps(s, rows=rows, frame_rows=height + blank, row_s=row_s)
        return aptina.check_trigger(s, busy_s=aptina.busy_s(rows=rows, height=height, row_s=row_s))

    def frame_period_s(self, state: Mapping[str, int]) -> float:
        rows = max(aptina.sensor_height(state) + vertical_blank(state), state["VEXPOS"] + 1)
        return rows * row_time_s(state["WOI_WIDTH"])

    def computed_registers(self, function: str, state: Mapping[str, int]) -> dict[str, int]:
        if function == WINDOW:
            return {
                "row_start": CLEAR_TOP + state["WOI_TOP"],
                "column_start": CLEAR_LEFT + state["WOI_LEFT"],
                "row_size": aptina.sensor_height(state) - 1,
                "column_size": state["WOI_WIDTH"] - 1,
            }
        if function == EXPOSURE:
            rows = state["VEXPOS"]
            return {"shutter_width_upper": rows >> 16, "shutter_width_lower": rows & 0xFFFF}
        if function == LIMITFPS:
            return {"horizontal_blank": HORIZONTAL_BLANK, "vertical_blank": vertical_blank(state)}
        return {}
