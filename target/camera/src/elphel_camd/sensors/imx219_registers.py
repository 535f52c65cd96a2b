"""Sony IMX219 (8 MPix, the Raspberry Pi camera v2): identity, geometry and register table.

Facts: shared/reference/frame-paths.md section 2 (the mainline kernel driver
drivers/media/i2c/imx219.c and its device-tree binding, the dissertation's Table 3).

The IMX219's registers are bytes at 16-bit addresses; a 16-bit value occupies two
consecutive addresses, high byte first, and one transfer may write or read several
consecutive bytes (the address auto-increments). The table declares each value once, at
its first address, with its width (8 or 16 bits): `elphel_camd.i2c.byte_registers`
moves that many bytes, and `register_bytes` says which addresses a register occupies.
Reset values not given by the reference are the mainline driver's full-resolution mode
(3280x2464 at 15 fps).
"""

from __future__ import annotations

from collections.abc import Iterator

from elphel_camd.sensors.registers import Access, Field, Register, RegisterTable

MODEL = "IMX219"
I2C_ADDRESS = 0x10
CHIP_ID = 0x0219
SENSOR_CODE = 0x219  # no Elphel code exists for this sensor; the chip id stands in
BAYER = "RGGB"  # the first active pixel, no flips
BITS = 10  # RAW10 output
PIXEL_PITCH_UM = 1.12
ARRAY_WIDTH = 3296  # native array
ARRAY_HEIGHT = 2480
ACTIVE_LEFT = 8  # the active area's origin in the native array
ACTIVE_TOP = 8
ACTIVE_WIDTH = 3280
ACTIVE_HEIGHT = 2464
INPUT_CLOCK_HZ = 24_000_000
PIXEL_RATE_HZ = 182_400_000  # the pixel rate of the mainline driver's modes
LINE_LENGTH_PIXELS = 3448  # line_length_pck of the mainline driver's modes

ANALOGUE_GAIN_CODE_MAX = 232  # gain 256 / (256 - 232) = 10.67
DIGITAL_GAIN_ONE = 0x0100  # digital gain is value / 256
DIGITAL_GAIN_MAX = 0x0FFF

MODE_STREAMING = 0x01
# 0x0174 / 0x0175 binning modes (horizontal, vertical).
BINNING_NONE = 0x00
BINNING_2X2 = 0x01
BINNING_ANALOG_2X2 = 0x03
BINNING_MODES = (BINNING_NONE, BINNING_2X2, BINNING_ANALOG_2X2)
DATA_FORMAT_RAW10 = 0x0A0A
DATA_FORMAT_RAW8 = 0x0808

MODE_SELECT_FIELDS = (Field("streaming", 0, doc="1 streaming, 0 software standby"),)
ORIENTATION_FIELDS = (
    Field("hflip", 0, doc="mirror horizontally (Bayer RGGB -> GRBG)"),
    Field("vflip", 1, doc="mirror vertically (Bayer RGGB -> GBRG)"),
)
DATA_FORMAT_FIELDS = (
    Field("input_bits", 15, 8, doc="bits per pixel read from the ADC (10)"),
    Field("output_bits", 7, 0, doc="bits per pixel sent over CSI-2 (10 RAW10, 8 RAW8)"),
)


TABLE = RegisterTable(
    MODEL,
    [
        Register("chip_id", 0x0000, CHIP_ID, Access.RO, doc="model id, 0x0219"),
        Register(
            "mode_select",
            0x0100,
            0,
            width=8,
            maximum=1,
            doc="bit 0: 1 streaming, 0 software standby",
            fields=MODE_SELECT_FIELDS,
        ),
        Register(
            "analogue_gain",
            0x0157,
            0,
            width=8,
            maximum=ANALOGUE_GAIN_CODE_MAX,
            unit="code",
            doc="analogue gain code c: gain 256 / (256 - c)",
        ),
        Register(
            "digital_gain",
            0x0158,
            DIGITAL_GAIN_ONE,
            minimum=DIGITAL_GAIN_ONE,
            maximum=DIGITAL_GAIN_MAX,
            unit="1/256",
            doc="digital gain, value / 256 (0x0100 = 1.0)",
        ),
        Register(
            "coarse_integration_time",
            0x015A,
            0x0640,
            unit="lines",
            doc="exposure in lines; 4 .. frame_length_lines - 4",
        ),
        Register(
            "frame_length_lines",
            0x0160,
            0x0DC6,
            unit="lines",
            doc="lines of a frame, blanking included",
        ),
        Register(
            "line_length_pck",
            0x0162,
            LINE_LENGTH_PIXELS,
            unit="pixels",
            doc="pixel clocks of a line (3448 in every mode)",
        ),
        Register(
            "x_addr_start", 0x0164, 0, maximum=ACTIVE_WIDTH - 1, unit="columns", doc="crop left"
        ),
        Register(
            "x_addr_end",
            0x0166,
            ACTIVE_WIDTH - 1,
            maximum=ACTIVE_WIDTH - 1,
            unit="columns",
            doc="crop right (inclusive)",
        ),
        Register("y_addr_start", 0x0168, 0, maximum=ACTIVE_HEIGHT - 1, unit="rows", doc="crop top"),
        Register(
            "y_addr_end",
            0x016A,
            ACTIVE_HEIGHT - 1,
            maximum=ACTIVE_HEIGHT - 1,
            unit="rows",
            doc="crop bottom (inclusive)",
        ),
        Register(
            "x_output_size",
            0x016C,
            ACTIVE_WIDTH,
            minimum=1,
            maximum=ACTIVE_WIDTH,
            unit="pixels",
            doc="output width: the crop's width, halved when binning",
        ),
        Register(
            "y_output_size",
            0x016E,
            ACTIVE_HEIGHT,
            minimum=1,
            maximum=ACTIVE_HEIGHT,
            unit="pixels",
            doc="output height: the crop's height, halved when binning",
        ),
        Register(
            "orientation",
            0x0172,
            0,
            width=8,
            maximum=3,
            doc="bit 0 hflip, bit 1 vflip",
            fields=ORIENTATION_FIELDS,
        ),
        Register(
            "binning_mode_h",
            0x0174,
            BINNING_NONE,
            width=8,
            maximum=BINNING_ANALOG_2X2,
            doc="horizontal binning: 0 none, 1 2x2, 3 analog 2x2",
        ),
        Register(
            "binning_mode_v",
            0x0175,
            BINNING_NONE,
            width=8,
            maximum=BINNING_ANALOG_2X2,
            doc="vertical binning: 0 none, 1 2x2, 3 analog 2x2",
        ),
        Register(
            "csi_data_format",
            0x018C,
            DATA_FORMAT_RAW10,
            doc="bits in (15:8) and out (7:0): 0x0A0A RAW10, 0x0808 RAW8",
            fields=DATA_FORMAT_FIELDS,
        ),
    ],
    address_bytes=2,
)


def register_bytes(register: Register) -> int:
    """Bytes a register's value occupies on the wire and in the chip's address space."""
    return 1 if register.width <= 8 else 2


def byte_addresses(table: RegisterTable) -> Iterator[tuple[int, Register, int]]:
    """Every byte address a table's registers occupy: (address, register, byte index).

    Byte index 0 is the most significant byte of a 16-bit value.
    """
    for r in table:
        for i in range(register_bytes(r)):
            yield r.address + i, r, i


def check_byte_layout(table: RegisterTable) -> None:
    """Raise ValueError if two registers of a byte-addressed table share a byte."""
    owner: dict[int, str] = {}
    for address, r, _ in byte_addresses(table):
        if address in owner:
            raise ValueError(
                f"{table.model}: {r.name} and {owner[address]} share byte 0x{address:04x}"
            )
        owner[address] = r.name


check_byte_layout(TABLE)

# What the driver writes once, after reading the shadows: RAW10 out, no binning.
INIT_WRITES: tuple[tuple[str, int], ...] = (
    ("csi_data_format", DATA_FORMAT_RAW10),
    ("binning_mode_h", BINNING_NONE),
    ("binning_mode_v", BINNING_NONE),
    ("line_length_pck", LINE_LENGTH_PIXELS),
)
