"""MT9P006 / MT9P031 (5 MPix): identity, geometry and the register table with its fields.

Facts: shared/reference/sensors.md section 1 (addresses, reset values and bit fields from
the datasheet, the Linux kernel driver and Elphel's driver, paraphrased).
"""

from __future__ import annotations

from elphel_camd.sensors.registers import Access, Field, Register, RegisterTable

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

# The layout of the four colour-gain registers and global_gain (reference 1.3).
GAIN_FIELDS = (
    Field("analog", 5, 0, doc="analog gain, value/8 (8 = 1.0x)"),
    Field("x2", 6, doc="x2 first analog stage"),
    Field("digital", 14, 8, doc="digital gain 1 + value/8 (Elphel leaves it 0)"),
)

# Bit fields of the registers that have them (reference 1.2).
OUTPUT_CONTROL_FIELDS = (
    Field("hold", 0, doc="1 = hold integration, gain, blanking, flip updates"),
    Field("chip_enable", 1, doc="0 stops readout; 0 -> 1 restarts the frame"),
    Field("pixclk_slew", 9, 7),
    Field("output_slew", 12, 10),
)

PIXEL_CLOCK_CONTROL_FIELDS = (
    Field("divide", 6, 0, doc="divider, powers of two"),
    Field("shift", 10, 8),
    Field("invert", 15),
)

RESTART_FIELDS = (
    Field("restart", 0, doc="restart the frame; self-clearing"),
    Field("pause", 1, doc="pause restart"),
    Field("trigger", 2, doc="software trigger, as the TRIGGER pin"),
)

RESET_FIELDS = (Field("soft_reset", 0, doc="1 = soft reset asserted, 0 = normal"),)

PLL_CONTROL_FIELDS = (Field("power", 0), Field("use", 1))

PLL_CONFIG_1_FIELDS = (Field("n_minus_1", 5, 0), Field("m", 15, 8))

PLL_CONFIG_2_FIELDS = (Field("p1_minus_1", 4, 0),)

READ_MODE_1_FIELDS = (
    Field("strobe_end", 1, 0),
    Field("strobe_start", 3, 2),
    Field("strobe_enable", 4),
    Field("strobe_invert", 5),
    Field("bulb", 6, doc="bulb exposure"),
    Field("global_reset", 7, doc="global reset release (GRR); 0 = ERS"),
    Field("snapshot", 8, doc="0 continuous, 1 wait for a trigger"),
    Field("invert_trigger", 9),
    Field("continuous_line_valid", 10),
    Field("xor_line_valid", 11),
)

READ_MODE_2_FIELDS = (
    Field("column_sum", 5, doc="sum when binning (0 = average)"),
    Field("row_blc", 6, doc="row-wise black level correction"),
    Field("show_dark_rows", 11),
    Field("show_dark_columns", 12),
    Field("mirror_column", 14, doc="horizontal flip"),
    Field("mirror_row", 15, doc="vertical flip"),
)

ROW_ADDRESS_MODE_FIELDS = (
    Field("row_skip", 2, 0, doc="skip - 1"),
    Field("row_bin", 5, 4, doc="bin - 1"),
)

COLUMN_ADDRESS_MODE_FIELDS = (
    Field("column_skip", 2, 0, doc="skip - 1"),
    Field("column_bin", 5, 4, doc="bin - 1"),
)

BLC_CONTROL_FIELDS = (Field("manual", 0, doc="manual black level correction"),)

TEST_PATTERN_FIELDS = (
    Field("enable", 0),
    Field("mode", 6, 3, doc="0 colour field, 1 h-gradient, 2 v-gradient, ..."),
)

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
        Register(
            "output_control",
            0x07,
            0x1F82,
            doc="bit 0 hold updates, bit 1 chip enable",
            fields=OUTPUT_CONTROL_FIELDS,
        ),
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
        Register(
            "pixel_clock_control",
            0x0A,
            0,
            doc="divide, shift, invert",
            fields=PIXEL_CLOCK_CONTROL_FIELDS,
        ),
        Register(
            "restart",
            0x0B,
            0,
            doc="bit 0 restart, bit 1 pause, bit 2 software trigger",
            fields=RESTART_FIELDS,
        ),
        Register("shutter_delay", 0x0C, 0, maximum=0x1FFF, doc="sub-row integration reduction"),
        Register(
            "reset",
            0x0D,
            0,
            maximum=1,
            doc="1 = soft reset asserted",
            fields=RESET_FIELDS,
        ),
        Register(
            "pll_control",
            0x10,
            0x0050,
            doc="bit 0 power PLL, bit 1 use PLL",
            fields=PLL_CONTROL_FIELDS,
        ),
        Register(
            "pll_config_1",
            0x11,
            0x6404,
            doc="M (15:8), N-1 (5:0)",
            fields=PLL_CONFIG_1_FIELDS,
        ),
        Register(
            "pll_config_2",
            0x12,
            0,
            maximum=0x1F,
            doc="P1-1",
            fields=PLL_CONFIG_2_FIELDS,
        ),
        Register(
            "read_mode_1",
            0x1E,
            0x4006,
            doc="bit 7 global reset release, bit 8 snapshot, bit 9 invert trigger",
            fields=READ_MODE_1_FIELDS,
        ),
        Register(
            "read_mode_2",
            0x20,
            0x0040,
            doc="bit 14 column mirror (FLIPH), bit 15 row mirror (FLIPV)",
            fields=READ_MODE_2_FIELDS,
        ),
        Register(
            "row_address_mode",
            0x22,
            0,
            maximum=0x37,
            doc="row skip (2:0), row bin (5:4)",
            fields=ROW_ADDRESS_MODE_FIELDS,
        ),
        Register(
            "column_address_mode",
            0x23,
            0,
            maximum=0x37,
            doc="column skip (2:0), column bin (5:4)",
            fields=COLUMN_ADDRESS_MODE_FIELDS,
        ),
        Register(
            "green1_gain",
            0x2B,
            0x0008,
            maximum=0x7F7F,
            doc="analog gain (5:0)/8, x2 stage (6), digital (14:8)",
            fields=GAIN_FIELDS,
        ),
        Register(
            "blue_gain", 0x2C, 0x0008, maximum=0x7F7F, doc="as green1_gain", fields=GAIN_FIELDS
        ),
        Register(
            "red_gain", 0x2D, 0x0008, maximum=0x7F7F, doc="as green1_gain", fields=GAIN_FIELDS
        ),
        Register(
            "green2_gain", 0x2E, 0x0008, maximum=0x7F7F, doc="as green1_gain", fields=GAIN_FIELDS
        ),
        Register(
            "global_gain",
            0x35,
            0x0008,
            maximum=0x7F7F,
            doc="writes all four colour gains",
            fields=GAIN_FIELDS,
        ),
        Register("row_black_target", 0x49, 0xA8, maximum=0xFFF, doc="row black target"),
        Register("row_black_default_offset", 0x4B, 0x28, maximum=0xFFF, doc="black offset"),
        Register(
            "blc_control",
            0x62,
            0,
            doc="bit 0 manual black level",
            fields=BLC_CONTROL_FIELDS,
        ),
        Register("reserved_7f", 0x7F, 0, doc="written 0 at init against blue blooming columns"),
        Register(
            "test_pattern",
            0xA0,
            0,
            doc="bit 0 enable, bits 6:3 mode",
            fields=TEST_PATTERN_FIELDS,
        ),
    ],
    address_bytes=1,
)

# Elphel's init writes (reference 1.2), after the shadows are read.
INIT_WRITES: tuple[tuple[str, int], ...] = (
    ("output_control", TABLE["output_control"].reset),
    ("reserved_7f", 0),  # against blue blooming columns
)
