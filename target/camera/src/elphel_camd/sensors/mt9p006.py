"""MT9P006 / MT9P031 (5 MPix): register table and identity.

Facts: shared/reference/sensors.md section 1 (addresses and reset values from the
datasheet, the Linux kernel driver and Elphel's driver, paraphrased).
"""

from __future__ import annotations

from elphel_camd.sensors.base import SensorDriver
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


# Elphel's minimum horizontal blanking without binning, in pixel clocks per row side
# (reference 1.4): a row lasts width + 2 * 450 pixel clocks.
HORIZONTAL_BLANK_MIN = 450


def row_time_s(width: int, *, clock_hz: int = SENSOR_CLOCK_HZ) -> float:
    """Duration of one row at a window width, as Elphel's timing model gives it."""
    return (width + 2 * HORIZONTAL_BLANK_MIN) / clock_hz


def decode_gain(code: int) -> float:
    """Total gain of a colour-gain register: (1 + digital/8) * (1 + x2 stage) * analog/8."""
    analog = code & 0x3F
    doubler = (code >> 6) & 1
    digital = (code >> 8) & 0x7F
    return (1 + digital / 8) * (1 + doubler) * analog / 8


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

    def read_params(self) -> dict[str, int]:
        words = self.io.read(0x01, 4)  # row start, column start, row size, column size
        row_start, column_start, row_size, column_size = words
        width = column_size + 1
        shutter_rows = (self.read("shutter_width_upper") << 16) | self.read("shutter_width_lower")
        read_mode_2 = self.read("read_mode_2")
        gains = {
            name: round(decode_gain(self.read(reg)) * 0x10000)
            for name, reg in (
                ("GAINR", "red_gain"),
                ("GAING", "green1_gain"),
                ("GAINGB", "green2_gain"),
                ("GAINB", "blue_gain"),
            )
        }
        return {
            "WOI_LEFT": column_start - CLEAR_LEFT,
            "WOI_TOP": row_start - CLEAR_TOP,
            "WOI_WIDTH": width,
            "WOI_HEIGHT": row_size + 1,
            "VEXPOS": shutter_rows,
            "EXPOS": round(shutter_rows * row_time_s(width) * 1e6),
            "FLIPH": (read_mode_2 >> 14) & 1,
            "FLIPV": (read_mode_2 >> 15) & 1,
            "BITS": BITS,
            "SENSOR": SENSOR_CODE,
            **gains,
        }
