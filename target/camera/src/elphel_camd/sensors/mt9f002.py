"""MT9F002 (14 MPix, HiSPi): gain code, Elphel's timing model and the driver.

Facts: shared/reference/sensors.md sections 2.3-2.4 (gain format, timing) and 3.3
(latencies). The register table, its bit fields and the model's identity are in
`elphel_camd.sensors.mt9f002_registers`.

Timing model (Elphel's, reference 2.4): exposure is coarse integration only (whole rows);
a row lasts ``line_length_pck`` VT clocks at 220 MHz, counted twice when the output is at
least 912 pixels wide. The frame is ``frame_length_lines`` rows, at least the window plus
the minimum frame blanking and at least one row longer than the exposure.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import ClassVar

from elphel_camd.params import (
    EXPOSURE,
    LIMITFPS,
    TRIG_PERIOD_MIN_REPEAT,
    TRIG_SNAPSHOT,
    TRIGGERMODE,
    WINDOW,
)
from elphel_camd.sensors import aptina
from elphel_camd.sensors.base import State
from elphel_camd.sensors.mt9f002_registers import (
    ARRAY_HEIGHT,
    ARRAY_WIDTH,
    BAYER,
    BITS,
    CHIP_ID,
    CLEAR_LEFT,
    CLEAR_TOP,
    I2C_ADDRESS,
    IMAGE_HEIGHT,
    IMAGE_WIDTH,
    INIT_WRITES,
    MODEL,
    PIXEL_ORDERS,
    PIXEL_PITCH_UM,
    SENSOR_CODE,
    TABLE,
    VT_PIX_CLK_HZ,
)
from elphel_camd.sensors.registers import FieldRule, FieldRules

__all__ = [
    "ARRAY_HEIGHT",
    "ARRAY_WIDTH",
    "BAYER",
    "CLEAR_LEFT",
    "CLEAR_TOP",
    "IMAGE_HEIGHT",
    "IMAGE_WIDTH",
    "INIT_WRITES",
    "MODEL",
    "MT9F002",
    "PIXEL_ORDERS",
    "PIXEL_PITCH_UM",
    "RULES",
    "TABLE",
    "VT_PIX_CLK_HZ",
    "decode_gain",
    "encode_gain",
    "row_clocks",
    "row_time_s",
]

# Row time (reference 2.4): outputs at least this wide use the datasheet minimum line
# length and count each line twice in VT clocks; narrower ones read back 0x930.
WIDE_OUTPUT = 912
LINE_LENGTH_WIDE_MIN = 0x4C8
LINE_LENGTH_NARROW_MIN = 0x930
LINE_LENGTH_OUTPUT_EXTRA = 0x5E  # (VT/OP) * x_output_size / 4 + 0x5E, VT/OP = 2
# Minimum vertical blanking: the reset frame length minus the reset window height; the
# reference has no datasheet figure.
FRAME_BLANKING_MIN = TABLE["frame_length_lines"].reset - TABLE["y_output_size"].reset
FRAME_LINES_MAX = 0xFFFF
CAMSYNC_HZ = 100_000_000  # TRIG_PERIOD counts 10 ns
COARSE_MAX = FRAME_LINES_MAX - 1  # the frame must stay one row longer than the exposure
GAIN_MIN = 0x18000  # 1.5x: colamp 1, analog2 48 (Elphel's smallest analog gain)
GAIN_MAX = 0xFE000  # 15.875x: colamp 3, analog2 127

# Parameters that are register fields (reference 2.2): flips in read_mode; the trigger
# mode in slave_mode, whose other bits are Elphel's constant 0x2000 (its reset value).
RULES = FieldRules(
    TABLE,
    [
        FieldRule(WINDOW, "FLIPH", "read_mode.flip_horizontal"),
        FieldRule(WINDOW, "FLIPV", "read_mode.flip_vertical"),
        FieldRule(TRIGGERMODE, "TRIG", "slave_mode.triggered", mask=TRIG_SNAPSHOT),
    ],
    from_reset=frozenset({"slave_mode"}),
)


def line_length_pck(width: int) -> int:
    """Row period register for an output width (Elphel's minimum, reference 2.4)."""
    floor = LINE_LENGTH_WIDE_MIN if width >= WIDE_OUTPUT else LINE_LENGTH_NARROW_MIN
    return max(floor, width // 2 + LINE_LENGTH_OUTPUT_EXTRA)


def row_clocks(width: int, line_length: int) -> int:
    """VT clocks of one row: Elphel counts the line twice for outputs >= 912 wide."""
    return line_length * (2 if width >= WIDE_OUTPUT else 1)


def row_time_s(width: int) -> float:
    """Duration of one row at an output width."""
    return row_clocks(width, line_length_pck(width)) / VT_PIX_CLK_HZ


_ANALOG2 = TABLE.field("green1_gain.analog2")  # every colour gain has this layout
_ANALOG3 = TABLE.field("green1_gain.analog3")
_COLAMP = TABLE.field("green1_gain.colamp")
_DIGITAL = TABLE.field("green1_gain.digital")


def decode_gain(code: int) -> float:
    """Total gain of a colour-gain register: digital * 2^colamp * 2^analog3 * analog2/64."""
    amplifiers = (1 << _COLAMP.get(code)) * (1 << _ANALOG3.get(code))
    return _DIGITAL.get(code) * amplifiers * _ANALOG2.get(code) / 64


def encode_gain(gain_16_16: int) -> int:
    """Colour-gain code for a 16.16 gain, analog only, as Elphel programs it.

    The column amplifier takes 2x below 3x, 4x below 6x, else 8x; analog2 (48..127, in
    1/64) makes up the rest; digital stays 1. The difference to the request is the
    residual.
    """
    gain = gain_16_16 / 0x10000
    colamp = 1 if gain < 3 else 2 if gain < 6 else 3
    analog2 = min(_ANALOG2.field.limit, max(48, round(gain * 64 / (1 << colamp))))
    return _ANALOG2.put(_COLAMP.put(_DIGITAL.put(0, 1), colamp), analog2)


def frame_lines(state: Mapping[str, int]) -> int:
    """frame_length_lines for a state (Elphel's pgm_limitfps and pgm_exposure).

    The window plus minimum blanking, stretched to the FP1000SLIM limit in free-run or to
    the trigger period (minus one row, so the sensor is back in slave mode before the next
    trigger) in snapshot mode, and at least one row longer than the exposure.
    """
    width = state["WOI_WIDTH"]
    row_s = row_time_s(width)
    lines = aptina.sensor_height(state) + FRAME_BLANKING_MIN
    period = state["TRIG_PERIOD"]
    if state["TRIG"] & TRIG_SNAPSHOT:
        if period >= TRIG_PERIOD_MIN_REPEAT:
            vt = period * (state["TRIG_DECIMATE"] + 1) * VT_PIX_CLK_HZ // CAMSYNC_HZ
            by_trigger = vt // row_clocks(width, line_length_pck(width)) - 1
            lines = max(lines, min(by_trigger, FRAME_LINES_MAX))
    elif state["FPSFLAGS"] & 1 and state["FP1000SLIM"]:
        lines = max(lines, math.ceil(1000 / state["FP1000SLIM"] / row_s))
    return max(lines, state["VEXPOS"] + 1)


class MT9F002(aptina.AptinaSensor):
    """Driver of the MT9F002 on its 16-bit-address (manufacturer) register map."""

    model = MODEL
    table = TABLE
    i2c_address = I2C_ADDRESS
    chip_id_register = "model_id"
    chip_id = CHIP_ID
    sensor_code = SENSOR_CODE
    bayer = BAYER
    bits = BITS
    image_width = IMAGE_WIDTH
    image_height = IMAGE_HEIGHT
    gain_min = GAIN_MIN
    gain_max = GAIN_MAX
    default_gain = GAIN_MIN
    exposure_rows_max = COARSE_MAX
    # Elphel's mt9f002 ahead table: window, exposure and frame length need 2 frames in
    # both modes.
    ahead: ClassVar[Mapping[str, tuple[int, int]]] = aptina.elphel_ahead(frame_snapshot=2)
    rules = RULES
    init_writes = INIT_WRITES
    init_rewrites = True  # Elphel writes every entry, whatever the chip holds
    encode_gain = staticmethod(encode_gain)
    decode_gain = staticmethod(decode_gain)
    row_time_s = staticmethod(row_time_s)

    def check_timing(self, s: State, *, height: int, rows: int, row_s: float) -> bool:
        snapshot = aptina.check_trigger(
            s, busy_s=aptina.busy_s(rows=rows, height=height, row_s=row_s)
        )
        lines = height + FRAME_BLANKING_MIN
        if not snapshot and s["FPSFLAGS"] & 1 and s["FP1000SLIM"]:
            wanted = math.ceil(1000 / s["FP1000SLIM"] / row_s)
            if wanted > FRAME_LINES_MAX:
                aptina.unreachable_fps_limit(s, row_s=row_s, max_rows=FRAME_LINES_MAX)
            lines = max(lines, wanted)
        aptina.check_keep_fps(s, rows=rows, frame_rows=lines, row_s=row_s)
        return snapshot

    def frame_period_s(self, state: Mapping[str, int]) -> float:
        return frame_lines(state) * row_time_s(state["WOI_WIDTH"])

    def computed_registers(self, function: str, state: Mapping[str, int]) -> dict[str, int]:
        if function == WINDOW:
            left = CLEAR_LEFT + state["WOI_LEFT"]
            top = CLEAR_TOP + state["WOI_TOP"]
            height = aptina.sensor_height(state)
            return {
                "x_addr_start": left,
                "x_addr_end": left + state["WOI_WIDTH"] - 1,
                "y_addr_start": top,
                "y_addr_end": top + height - 1,
                "x_output_size": state["WOI_WIDTH"],
                "y_output_size": height,
            }
        if function == EXPOSURE:
            return {"coarse_integration_time": state["VEXPOS"]}
        if function == LIMITFPS:
            return {
                "line_length_pck": line_length_pck(state["WOI_WIDTH"]),
                "frame_length_lines": frame_lines(state),
            }
        return {}
