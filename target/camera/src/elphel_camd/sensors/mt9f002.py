"""MT9F002 (14 MPix, HiSPi, 16-bit register addresses): register table and driver.

Facts: shared/reference/sensors.md section 2 (manufacturer register addresses, reset
values from Elphel's header comment, the combined colour-gain format, Elphel's timing
model) and section 3.3 (latencies). Where the reference has no reset value for a register
the table says so in the register's doc and the value is the one Elphel's init writes.

Timing model (Elphel's, reference 2.4): exposure is coarse integration only (whole rows);
a row lasts ``line_length_pck`` VT clocks at 220 MHz, counted twice when the output is at
least 912 pixels wide. The frame is ``frame_length_lines`` rows, at least the window plus
the minimum frame blanking and at least one row longer than the exposure.
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
    TRIG_PERIOD_MIN_REPEAT,
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

MODEL = "MT9F002"
I2C_ADDRESS = 0x10
CHIP_ID = 0x2E01  # Elphel requires an exact match
SENSOR_CODE = 0x38  # Elphel's SENSOR_MT9F002
BAYER = "GRBG"  # pixel_order 0: the first pixel of an unflipped window at even offsets
PIXEL_ORDERS = ("GRBG", "RGGB", "BGGR", "GBRG")  # pixel_order register values 0..3
PIXEL_PITCH_UM = 1.4
IMAGE_WIDTH = 4384  # 14 Mp still mode, Elphel's default window
IMAGE_HEIGHT = 3288
ARRAY_WIDTH = 4640
ARRAY_HEIGHT = 3320
CLEAR_LEFT = 144  # Elphel's clearLeft / clearTop: x/y_addr_start of WOI_LEFT/TOP = 0
CLEAR_TOP = 32
BITS = 12  # HiSPi 12-bit (Elphel's FPGA module sens_hispi12l4)
VT_PIX_CLK_HZ = 220_000_000

# Row time (reference 2.4): outputs at least this wide use the datasheet minimum line
# length and count each line twice in VT clocks; narrower ones read back 0x930.
WIDE_OUTPUT = 912
LINE_LENGTH_WIDE_MIN = 0x4C8
LINE_LENGTH_NARROW_MIN = 0x930
LINE_LENGTH_OUTPUT_EXTRA = 0x5E  # (VT/OP) * x_output_size / 4 + 0x5E, VT/OP = 2
# Minimum vertical blanking: the reset frame length (0x0D6A) minus the reset window
# height (3288 rows); the reference has no datasheet figure.
FRAME_BLANKING_MIN = 0x0D6A - IMAGE_HEIGHT
FRAME_LINES_MAX = 0xFFFF
CAMSYNC_HZ = 100_000_000  # TRIG_PERIOD counts 10 ns
COARSE_MAX = FRAME_LINES_MAX - 1  # the frame must stay one row longer than the exposure
GAIN_MIN = 0x18000  # 1.5x: colamp 1, analog2 48 (Elphel's smallest analog gain)
GAIN_MAX = 0xFE000  # 15.875x: colamp 3, analog2 127
SLAVE_MODE_FREE_RUN = 0x2000
SLAVE_MODE_TRIGGERED = 0xA000
READ_MODE_FLIPH = 0x4000
READ_MODE_FLIPV = 0x8000

TABLE = RegisterTable(
    MODEL,
    [
        # SMIA-only registers (no manufacturer alias).
        Register("vt_pix_clk_div", 0x0300, 6, maximum=0xF, doc="VT pixel clock divider"),
        Register("vt_sys_clk_div", 0x0302, 1, maximum=0x1F, doc="VT system clock divider"),
        Register("pre_pll_clk_div", 0x0304, 6, maximum=0x3F, doc="PLL input divider"),
        Register(
            "pll_multiplier",
            0x0306,
            0xA5,
            maximum=0xFF,
            doc="PLL multiplier; reset 0xA5 (24 MHz), Elphel writes 0xB4 for 22 MHz EXTCLK",
        ),
        Register("op_pix_clk_div", 0x0308, 0xC, maximum=0x1F, doc="output pixel clock divider"),
        Register("op_sys_clk_div", 0x030A, 1, maximum=0x1F, doc="output system clock divider"),
        Register(
            "x_output_size",
            0x034C,
            IMAGE_WIDTH,
            minimum=2,
            maximum=ARRAY_WIDTH,
            unit="columns",
            doc="columns output per row",
        ),
        Register(
            "y_output_size",
            0x034E,
            IMAGE_HEIGHT,
            minimum=2,
            maximum=ARRAY_HEIGHT,
            unit="rows",
            doc="rows output per frame",
        ),
        # Manufacturer registers.
        Register("model_id", 0x3000, CHIP_ID, Access.RO, doc="model id, 0x2E01"),
        Register(
            "y_addr_start",
            0x3002,
            0x0020,
            maximum=ARRAY_HEIGHT - 1,
            unit="rows",
            doc="first row read (even)",
        ),
        Register(
            "x_addr_start",
            0x3004,
            0x0090,
            maximum=ARRAY_WIDTH - 1,
            unit="columns",
            doc="first column read (even)",
        ),
        Register(
            "y_addr_end",
            0x3006,
            0x0CF7,
            maximum=ARRAY_HEIGHT - 1,
            unit="rows",
            doc="last row read (odd)",
        ),
        Register(
            "x_addr_end",
            0x3008,
            0x11AF,
            maximum=ARRAY_WIDTH - 1,
            unit="columns",
            doc="last column read (odd)",
        ),
        Register(
            "frame_length_lines",
            0x300A,
            0x0D6A,
            minimum=1,
            unit="rows",
            doc="frame period in rows (window, blanking, and more than the exposure)",
        ),
        Register(
            "line_length_pck",
            0x300C,
            0x2350,
            minimum=1,
            unit="vt clocks",
            doc="row period in VT clocks (Elphel counts it twice for outputs >= 912 wide)",
        ),
        Register(
            "fine_correction", 0x3010, 0x0128, doc="must change with binning / pixel clock speed"
        ),
        Register(
            "coarse_integration_time",
            0x3012,
            0x0010,
            unit="rows",
            doc="exposure in rows (Elphel uses coarse integration only)",
        ),
        Register(
            "fine_integration_time",
            0x3014,
            0x0524,
            unit="vt clocks",
            doc="sub-row exposure; left at reset (Elphel ignores it)",
        ),
        Register(
            "reset_register",
            0x301A,
            0x011C,
            doc="bit 9 masks broken frames, bit 3 guards RO registers; reset value not in "
            "the reference, Elphel writes 0x011C after init",
        ),
        Register(
            "pixel_order",
            0x3024,
            0,
            Access.RO,
            maximum=3,
            doc="colour of the first pixel: 0 GRBG, 1 RGGB, 2 BGGR, 3 GBRG (follows the flips)",
        ),
        Register(
            "gpi_status",
            0x3026,
            0xFCFF,
            doc="Elphel writes 0xFCFF: GPI1 is the trigger input (reset value not in the "
            "reference)",
        ),
        Register(
            "analog_gain_code_global",
            0x3028,
            0x000A,
            maximum=0x7F,
            doc="SMIA analog gain code, all colours; Elphel init 0x000A (reset not in the "
            "reference)",
        ),
        Register(
            "analog_gain_code_red",
            0x302C,
            0x000D,
            maximum=0x7F,
            doc="SMIA analog gain code, red; Elphel init 0x000D (reset not in the reference)",
        ),
        Register(
            "analog_gain_code_blue",
            0x302E,
            0x0010,
            maximum=0x7F,
            doc="SMIA analog gain code, blue; Elphel init 0x0010 (reset not in the reference)",
        ),
        Register(
            "read_mode",
            0x3040,
            0x0041,
            doc="bit 15 vertical flip, bit 14 horizontal flip, bits 8:6 x_odd_inc, "
            "bits 5:0 y_odd_inc",
        ),
        Register(
            "green1_gain",
            0x3056,
            0x1430,
            doc="digital (15:12) x 2^colamp (11:10) x 2^analog3 (9:7) x analog2 (6:0)/64; "
            "reset not in the reference, 1.5x assumed",
        ),
        Register("blue_gain", 0x3058, 0x1430, doc="as green1_gain"),
        Register("red_gain", 0x305A, 0x1430, doc="as green1_gain"),
        Register("green2_gain", 0x305C, 0x1430, doc="as green1_gain"),
        Register("global_gain", 0x305E, 0x1430, doc="writes all four colour gains"),
        Register(
            "datapath_select",
            0x306E,
            0x9280,
            doc="data path; Elphel init 0x9280 (reset not in the reference)",
        ),
        Register("test_pattern_mode", 0x3070, 0, doc="0 off, 2 stripes (Elphel's TESTSENSOR)"),
        Register(
            "slave_mode",
            0x3158,
            SLAVE_MODE_FREE_RUN,
            doc="0x2000 free-run (no GRR), 0xA000 triggered (TRIG=4); other bits and the "
            "reset value not in the reference",
        ),
        Register(
            "hispi_timing",
            0x31C0,
            0x8000,
            doc="HiSPi lane timing; Elphel init 0x8000 (reset not in the reference)",
        ),
        Register(
            "hispi_control_status",
            0x31C6,
            0x8400,
            doc="HiSPi control; Elphel init 0x8400 (reset not in the reference)",
        ),
    ],
    address_bytes=2,
)

# Elphel's init list (reference 2.2), in order; reset_register last.
INIT_WRITES: tuple[tuple[str, int], ...] = (
    ("hispi_timing", 0x8000),
    ("pll_multiplier", 0xB4),
    ("hispi_control_status", 0x8400),
    ("datapath_select", 0x9280),
    ("analog_gain_code_global", 0x000A),
    ("analog_gain_code_red", 0x000D),
    ("analog_gain_code_blue", 0x0010),
    ("coarse_integration_time", 0x0100),
    ("slave_mode", SLAVE_MODE_FREE_RUN),
    ("gpi_status", 0xFCFF),
    ("reset_register", 0x011C),
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


def decode_gain(code: int) -> float:
    """Total gain of a colour-gain register: digital * 2^colamp * 2^analog3 * analog2/64."""
    analog2 = code & 0x7F
    analog3 = (code >> 7) & 0x7
    colamp = (code >> 10) & 0x3
    digital = (code >> 12) & 0xF
    return digital * (1 << colamp) * (1 << analog3) * analog2 / 64


def encode_gain(gain_16_16: int) -> int:
    """Colour-gain code for a 16.16 gain, analog only, as Elphel programs it.

    The column amplifier takes 2x below 3x, 4x below 6x, else 8x; analog2 (48..127, in
    1/64) makes up the rest; digital stays 1. The difference to the request is the
    residual.
    """
    gain = gain_16_16 / 0x10000
    colamp = 1 if gain < 3 else 2 if gain < 6 else 3
    analog2 = min(127, max(48, round(gain * 64 / (1 << colamp))))
    return 0x1000 | colamp << 10 | analog2


def frame_lines(state: Mapping[str, int]) -> int:
    """frame_length_lines for a state (Elphel's pgm_limitfps and pgm_exposure).

    The window plus minimum blanking, stretched to the FP1000SLIM limit in free-run or to
    the trigger period (minus one row, so the sensor is back in slave mode before the next
    trigger) in snapshot mode, and at least one row longer than the exposure.
    """
    width = state["WOI_WIDTH"]
    row_s = row_time_s(width)
    lines = sensor_height(state) + FRAME_BLANKING_MIN
    period = state["TRIG_PERIOD"]
    if state["TRIG"] & TRIG_SNAPSHOT:
        if period >= TRIG_PERIOD_MIN_REPEAT:
            vt = period * (state["TRIG_DECIMATE"] + 1) * VT_PIX_CLK_HZ // CAMSYNC_HZ
            by_trigger = vt // row_clocks(width, line_length_pck(width)) - 1
            lines = max(lines, min(by_trigger, FRAME_LINES_MAX))
    elif state["FPSFLAGS"] & 1 and state["FP1000SLIM"]:
        lines = max(lines, math.ceil(1000 / state["FP1000SLIM"] / row_s))
    return max(lines, state["VEXPOS"] + 1)


class MT9F002(SensorDriver):
    """Driver of the MT9F002 on its 16-bit-address (manufacturer) register map."""

    model = MODEL
    table = TABLE
    i2c_address = I2C_ADDRESS
    chip_id_register = "model_id"
    chip_id = CHIP_ID
    sensor_code = SENSOR_CODE
    bayer = BAYER
    bits = BITS
    # Elphel's mt9f002 ahead table (continuous SKIP=0, async SKIP=0 columns): window,
    # exposure and frame length need 2 frames in both modes.
    ahead: ClassVar[Mapping[str, tuple[int, int]]] = {
        TRIGGERMODE: (2, 1),
        WINDOW: (2, 2),
        GAINS: (1, 1),
        LIMITFPS: (2, 2),
        EXPOSURE: (2, 2),
        TRIGSEQ: (2, 1),
    }
    writable = WRITABLE

    def init(self) -> None:
        """Read the shadows, then write Elphel's init list (every entry, whatever it read)."""
        super().init()
        for name, value in INIT_WRITES:
            self.write(name, value)

    def defaults(self) -> State:
        state = default_state(width=IMAGE_WIDTH, height=IMAGE_HEIGHT, gain=GAIN_MIN)
        return self.normalize(state, frozenset({"EXPOS"}))

    def normalize(self, state: Mapping[str, int], changed: frozenset[str]) -> State:
        s = dict(state)
        height = check_window_and_modes(
            s,
            image_width=IMAGE_WIDTH,
            image_height=IMAGE_HEIGHT,
            gains=GAIN_REGISTERS,
            gain_min=GAIN_MIN,
            gain_max=GAIN_MAX,
        )
        row_s = row_time_s(s["WOI_WIDTH"])
        rows = set_exposure_rows(s, changed, row_s=row_s, max_rows=COARSE_MAX)
        snapshot = check_trigger(s, busy_s=(rows + height + 9) * row_s)
        lines = height + FRAME_BLANKING_MIN
        if not snapshot and s["FPSFLAGS"] & 1 and s["FP1000SLIM"]:
            wanted = math.ceil(1000 / s["FP1000SLIM"] / row_s)
            if wanted > FRAME_LINES_MAX:
                lowest = math.ceil(1000 / (row_s * FRAME_LINES_MAX))
                raise ParameterRangeError(
                    "FP1000SLIM",
                    s["FP1000SLIM"],
                    f">= {lowest} at this window (or FPSFLAGS bit 0 off)",
                )
            lines = max(lines, wanted)
        if s["FPSFLAGS"] & 2 and rows >= lines:
            longest = round((lines - 1) * row_s * 1e6)
            raise ParameterRangeError(
                "EXPOS", s["EXPOS"], f"1..{longest} us while FPSFLAGS bit 1 keeps the frame rate"
            )
        if snapshot:
            s["FP1000S"] = trigger_fps1000(s)
        else:
            s["FP1000S"] = round(1000 / self.frame_period_s(s))
        s["SENSOR"] = SENSOR_CODE
        s["COLOR"] = 15
        s["BITS"] = 16
        return s

    def frame_period_s(self, state: Mapping[str, int]) -> float:
        return frame_lines(state) * row_time_s(state["WOI_WIDTH"])

    def registers(self, function: str, state: Mapping[str, int]) -> dict[str, int]:
        if function == WINDOW:
            flips = (READ_MODE_FLIPH if state["FLIPH"] else 0) | (
                READ_MODE_FLIPV if state["FLIPV"] else 0
            )
            read_mode = (self.shadow.get("read_mode", 0x0041) & 0x3FFF) | flips
            left = CLEAR_LEFT + state["WOI_LEFT"]
            top = CLEAR_TOP + state["WOI_TOP"]
            height = sensor_height(state)
            return {
                "x_addr_start": left,
                "x_addr_end": left + state["WOI_WIDTH"] - 1,
                "y_addr_start": top,
                "y_addr_end": top + height - 1,
                "x_output_size": state["WOI_WIDTH"],
                "y_output_size": height,
                "read_mode": read_mode,
            }
        if function == EXPOSURE:
            return {"coarse_integration_time": state["VEXPOS"]}
        if function == GAINS:
            return {reg: encode_gain(state[name]) for name, reg in GAIN_REGISTERS.items()}
        if function == TRIGGERMODE:
            triggered = state["TRIG"] & TRIG_SNAPSHOT
            return {"slave_mode": SLAVE_MODE_TRIGGERED if triggered else SLAVE_MODE_FREE_RUN}
        if function == LIMITFPS:
            return {
                "line_length_pck": line_length_pck(state["WOI_WIDTH"]),
                "frame_length_lines": frame_lines(state),
            }
        return {}

    def actual_gains(self, state: Mapping[str, int]) -> dict[str, int]:
        """16.16 gains the register codes really give (the request minus its residual)."""
        return {
            name: round(decode_gain(encode_gain(state[name])) * 0x10000) for name in GAIN_REGISTERS
        }
