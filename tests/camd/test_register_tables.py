"""Register tables check themselves and match the reference facts; the sim chips use them.

Per-sensor facts are parametrised over the sensors: MT9P006, MT9F002 and the Lepton 3.5's
CCI registers.
"""

import pytest

from elphel_camd.sensors import (
    DRIVERS,
    IMX219,
    MT9F002,
    MT9P006,
    Lepton35,
    RegisterFileSensor,
    cci,
)
from elphel_camd.sensors import mt9f002 as f002
from elphel_camd.sensors import mt9p006 as p006
from elphel_camd.sensors.registers import Access, Register, RegisterTable
from elphel_sim.chips.lepton35 import SimLepton35
from elphel_sim.chips.mt9f002 import SimMT9F002
from elphel_sim.chips.mt9p006 import SimMT9P006

REGISTER_FILE_DRIVERS = [d for d in DRIVERS if issubclass(d, RegisterFileSensor)]


def test_detection_order():
    assert (MT9P006, MT9F002, Lepton35, IMX219) == DRIVERS


def test_overlapping_addresses_are_rejected():
    with pytest.raises(ValueError, match="share address"):
        RegisterTable("X", [Register("a", 1, 0), Register("b", 1, 0)], address_bytes=1)


def test_duplicate_names_and_bad_limits_are_rejected():
    with pytest.raises(ValueError, match="declared twice"):
        RegisterTable("X", [Register("a", 1, 0), Register("a", 2, 0)], address_bytes=1)
    with pytest.raises(ValueError, match="do not fit"):
        RegisterTable("X", [Register("a", 1, 0, maximum=300, width=8)], address_bytes=1)
    with pytest.raises(ValueError, match="reset"):
        RegisterTable("X", [Register("a", 1, 5, maximum=4)], address_bytes=1)
    with pytest.raises(ValueError, match="bus width"):
        RegisterTable("X", [Register("a", 0x100, 0)], address_bytes=1)


def test_register_check_names_value_and_range():
    with pytest.raises(ValueError, match=r"row_start \(0x1\) = 3000; allowed 0..2004"):
        p006.TABLE["row_start"].check(3000)


@pytest.mark.parametrize("driver", REGISTER_FILE_DRIVERS, ids=lambda d: d.model)
def test_every_register_file_driver_table_is_consistent(driver):
    table = driver.table
    assert driver.chip_id_register in table
    chip = table[driver.chip_id_register]
    assert chip.access is Access.RO and chip.reset == driver.chip_id
    for r in table:
        assert r.doc, f"{driver.model} {r.name} has no doc"


def test_the_lepton_cci_table_is_consistent():
    # The Lepton is identified by its CCI status word: booted, not busy.
    status = cci.REGISTERS["status"]
    assert status.access is Access.RO and status.reset == cci.STATUS_READY
    for r in cci.REGISTERS:
        assert r.doc, f"CCI {r.name} has no doc"


@pytest.mark.parametrize(
    ("table", "name", "address", "reset"),
    [
        (p006.TABLE, "chip_version", 0x00, 0x1801),
        (p006.TABLE, "shutter_width_lower", 0x09, 0x0797),
        (p006.TABLE, "read_mode_2", 0x20, 0x0040),
        (p006.TABLE, "global_gain", 0x35, None),
        (f002.TABLE, "model_id", 0x3000, 0x2E01),
        (f002.TABLE, "y_addr_start", 0x3002, 0x0020),
        (f002.TABLE, "x_addr_start", 0x3004, 0x0090),
        (f002.TABLE, "y_addr_end", 0x3006, 0x0CF7),
        (f002.TABLE, "x_addr_end", 0x3008, 0x11AF),
        (f002.TABLE, "frame_length_lines", 0x300A, 0x0D6A),
        (f002.TABLE, "line_length_pck", 0x300C, 0x2350),
        (f002.TABLE, "fine_correction", 0x3010, 0x0128),
        (f002.TABLE, "coarse_integration_time", 0x3012, 0x0010),
        (f002.TABLE, "fine_integration_time", 0x3014, 0x0524),
        (f002.TABLE, "read_mode", 0x3040, 0x0041),
        (f002.TABLE, "pll_multiplier", 0x0306, 0xA5),
        (cci.REGISTERS, "power", 0x0000, None),
        (cci.REGISTERS, "status", 0x0002, 0x0006),
        (cci.REGISTERS, "command", 0x0004, None),
        (cci.REGISTERS, "data_length", 0x0006, None),
        (cci.REGISTERS, "data_crc", 0x0028, None),
    ],
    ids=lambda v: v.model if isinstance(v, RegisterTable) else None,
)
def test_reference_addresses_and_resets(table, name, address, reset):
    register = table[name]
    assert register.address == address
    if reset is not None:
        assert register.reset == reset


def test_mt9f002_gain_and_control_addresses():
    addresses = {r.name: r.address for r in f002.TABLE}
    assert addresses["green1_gain"] == 0x3056 and addresses["blue_gain"] == 0x3058
    assert addresses["red_gain"] == 0x305A and addresses["green2_gain"] == 0x305C
    assert addresses["global_gain"] == 0x305E and addresses["slave_mode"] == 0x3158
    assert addresses["reset_register"] == 0x301A and addresses["pixel_order"] == 0x3024
    assert f002.TABLE.address_bytes == 2
    assert all(r.address % 2 == 0 for r in f002.TABLE)  # 16-bit registers, byte-addressed


def test_mt9f002_reset_window_is_elphels_geometry():
    t = f002.TABLE
    assert t["x_addr_start"].reset == f002.CLEAR_LEFT and t["y_addr_start"].reset == f002.CLEAR_TOP
    assert t["x_addr_end"].reset - t["x_addr_start"].reset + 1 == f002.IMAGE_WIDTH
    assert t["y_addr_end"].reset - t["y_addr_start"].reset + 1 == f002.IMAGE_HEIGHT
    assert t["y_addr_end"].reset < f002.ARRAY_HEIGHT and t["x_addr_end"].reset < f002.ARRAY_WIDTH


@pytest.mark.parametrize(
    ("spec", "code", "gain"),
    [
        (p006, 0x0008, 1.0),
        (p006, 0x0010, 2.0),
        (p006, 0x0060, 8.0),
        (p006, 0x0860, 16.0),
        (p006, 0x007F, 15.75),
        (f002, 0x1430, 1.5),
        (f002, 0x1440, 2.0),
        (f002, 0x1830, 3.0),
        (f002, 0x1C40, 8.0),
        (f002, 0x1C7F, 15.875),
    ],
    ids=lambda v: v.MODEL if hasattr(v, "MODEL") else None,
)
def test_gain_code(spec, code, gain):
    assert spec.decode_gain(code) == pytest.approx(gain)


def test_mt9f002_gain_codes_cover_elphels_range_monotonically():
    gains = [f002.decode_gain(f002.encode_gain(g)) for g in range(0x18000, 0xFE001, 0x800)]
    assert gains == sorted(gains)
    assert gains[0] == 1.5 and gains[-1] == 15.875
    for g in range(0x18000, 0xFE001, 0x800):
        assert abs(f002.decode_gain(f002.encode_gain(g)) - g / 0x10000) <= g / 0x10000 / 96


def test_lepton_cci_registers():
    t = cci.REGISTERS
    assert (t["power"].address, t["status"].address, t["command"].address) == (0, 2, 4)
    assert t["data_length"].address == 0x0006 and t["data_crc"].address == 0x0028
    assert [t[f"data{i}"].address for i in range(16)] == list(range(0x0008, 0x0028, 2))
    assert t["status"].access is Access.RO and t["status"].reset == 0x0006
    assert (cci.REG_STATUS, cci.REG_COMMAND, cci.REG_DATA0) == (0x0002, 0x0004, 0x0008)
    assert (cci.STATUS_BUSY, cci.STATUS_READY, cci.STATUS_RESERVED) == (0x1, 0x6, 0xF8)


def test_lepton_command_table_walk():
    for command in cci.COMMANDS.values():
        protected = command.module in (cci.Module.OEM, cci.Module.RAD)
        assert bool(command.base & cci.PROTECTION_BIT) == protected, command.name
        assert command.base >> 8 & 0xF == command.module, command.name
        assert command.base & 0x3 == 0 and command.doc, command.name
        assert 0 <= command.words <= cci.DATA_WORDS
    bases = {c.name: c.base for c in cci.COMMANDS.values()}
    assert bases["SYS_FPA_TEMPERATURE"] == 0x0214 and bases["OEM_GPIO_MODE"] == 0x4854
    assert bases["RAD_ENABLE"] == 0x4E10 and bases["RAD_TLINEAR_ENABLE"] == 0x4EC0
    assert bases["RAD_TLINEAR_RESOLUTION"] == 0x4EC4 and bases["SYS_RUN_FFC"] == 0x0240
    assert bases["SYS_TELEMETRY_ENABLE"] == 0x0218 and bases["SYS_TELEMETRY_LOCATION"] == 0x021C


def test_duplicate_commands_are_rejected():
    c = cci.Command("A", cci.Module.SYS, 0x14, 1, frozenset({cci.CommandType.GET}))
    with pytest.raises(ValueError, match="declared twice"):
        cci._table([c, c])
    with pytest.raises(ValueError, match="share 0x0214"):
        cci._table([c, cci.Command("B", cci.Module.SYS, 0x14, 1, c.kinds)])


@pytest.mark.parametrize(
    ("chip", "table", "chip_id_register", "chip_id"),
    [
        (SimMT9P006, p006.TABLE, "chip_version", 0x1801),
        (SimMT9F002, f002.TABLE, "model_id", 0x2E01),
        (SimLepton35, cci.REGISTERS, "status", 0x0006),
    ],
    ids=lambda v: v.__name__ if isinstance(v, type) else None,
)
def test_simulated_chips_are_built_from_the_same_tables(chip, table, chip_id_register, chip_id):
    assert chip().table is table
    assert set(chip().values) == {r.address for r in table}
    assert chip().peek(chip_id_register) == chip_id
