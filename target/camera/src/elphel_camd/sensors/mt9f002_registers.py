"""MT9F002 (14 MPix, HiSPi, 16-bit register addresses): identity, geometry, register table.

Facts: shared/reference/sensors.md section 2 (manufacturer register addresses, reset
values from Elphel's header comment, the combined colour-gain format). Where the reference
has no reset value for a register the table says so in the register's doc and the value
is the one Elphel's init writes.
"""

from __future__ import annotations

from elphel_camd.sensors.registers import Access, Field, Register, RegisterTable

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
SLAVE_MODE_FREE_RUN = 0x2000

# The layout of the four colour-gain registers and global_gain (reference 2.3).
GAIN_FIELDS = (
    Field("analog2", 6, 0, doc="fine analog gain, value/64"),
    Field("analog3", 9, 7, doc="analog gain 2^value"),
    Field("colamp", 11, 10, doc="column amplifier 2^value"),
    Field("digital", 15, 12, doc="digital gain x value (Elphel writes 1)"),
)

# Bit fields of the registers that have them (reference 2.2).
RESET_REGISTER_FIELDS = (
    Field("lock_registers", 3, doc="0 allows writing some read-only registers"),
    Field("mask_bad_frames", 9, doc="1 masks broken frames"),
)

PIXEL_ORDER_FIELDS = (
    Field("column", 0, doc="the first pixel is an odd column of the GRBG cell"),
    Field("row", 1, doc="the first pixel is an odd row of the GRBG cell"),
)

READ_MODE_FIELDS = (
    Field("y_odd_inc", 5, 0, doc="1 normal, 3, 7, ... 63 skipping"),
    Field("x_odd_inc", 8, 6, doc="1 normal, 3 = 1/2, 7 = 1/4"),
    Field("xy_bin", 10, doc="x and y binning"),
    Field("x_bin_analog", 11, doc="x analog binning"),
    Field("flip_horizontal", 14, doc="horizontal flip (FLIPH)"),
    Field("flip_vertical", 15, doc="vertical flip: start from y_addr_end (FLIPV)"),
)

SLAVE_MODE_FIELDS = (Field("triggered", 15, doc="1 waits for the trigger (Elphel's 0xA000)"),)

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
            fields=RESET_REGISTER_FIELDS,
        ),
        Register(
            "pixel_order",
            0x3024,
            0,
            Access.RO,
            maximum=3,
            doc="colour of the first pixel: 0 GRBG, 1 RGGB, 2 BGGR, 3 GBRG (follows the flips)",
            fields=PIXEL_ORDER_FIELDS,
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
            fields=READ_MODE_FIELDS,
        ),
        Register(
            "green1_gain",
            0x3056,
            0x1430,
            doc="digital (15:12) x 2^colamp (11:10) x 2^analog3 (9:7) x analog2 (6:0)/64; "
            "reset not in the reference, 1.5x assumed",
            fields=GAIN_FIELDS,
        ),
        Register("blue_gain", 0x3058, 0x1430, doc="as green1_gain", fields=GAIN_FIELDS),
        Register("red_gain", 0x305A, 0x1430, doc="as green1_gain", fields=GAIN_FIELDS),
        Register("green2_gain", 0x305C, 0x1430, doc="as green1_gain", fields=GAIN_FIELDS),
        Register(
            "global_gain", 0x305E, 0x1430, doc="writes all four colour gains", fields=GAIN_FIELDS
        ),
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
            fields=SLAVE_MODE_FIELDS,
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
