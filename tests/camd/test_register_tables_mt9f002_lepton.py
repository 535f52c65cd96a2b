"""The MT9F002 and Lepton 3.5 tables match the reference facts; the sim chips use them."""

import pytest

from elphel_camd.sensors import DRIVERS, MT9F002, MT9P006, Lepton35, cci
from elphel_camd.sensors import lepton35 as lep
from elphel_camd.sensors import mt9f002 as f002
from elphel_camd.sensors.registers import Access
from elphel_sim.chips.lepton35 import SimLepton35
from elphel_sim.chips.mt9f002 import SimMT9F002


def test_detection_order():
    assert (MT9P006, MT9F002, Lepton35) == DRIVERS


@pytest.mark.parametrize(
    ("name", "address", "reset"),
    [
        ("model_id", 0x3000, 0x2E01),
        ("y_addr_start", 0x3002, 0x0020),
        ("x_addr_start", 0x3004, 0x0090),
        ("y_addr_end", 0x3006, 0x0CF7),
        ("x_addr_end", 0x3008, 0x11AF),
        ("frame_length_lines", 0x300A, 0x0D6A),
        ("line_length_pck", 0x300C, 0x2350),
        ("fine_correction", 0x3010, 0x0128),
        ("coarse_integration_time", 0x3012, 0x0010),
        ("fine_integration_time", 0x3014, 0x0524),
        ("read_mode", 0x3040, 0x0041),
        ("pll_multiplier", 0x0306, 0xA5),
    ],
)
def test_mt9f002_reference_addresses_and_resets(name, address, reset):
    register = f002.TABLE[name]
    assert (register.address, register.reset) == (address, reset)


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


def test_mt9f002_gain_codes_cover_elphels_range_monotonically():
    gains = [f002.decode_gain(f002.encode_gain(g)) for g in range(0x18000, 0xFE001, 0x800)]
    assert gains == sorted(gains)
    assert gains[0] == 1.5 and gains[-1] == 15.875
    for g in range(0x18000, 0xFE001, 0x800):
        assert abs(f002.decode_gain(f002.encode_gain(g)) - g / 0x10000) <= g / 0x10000 / 96


def test_lepton_cci_registers():
    t = lep.TABLE
    assert (t["power"].address, t["status"].address, t["command"].address) == (0, 2, 4)
    assert t["data_length"].address == 0x0006 and t["data_crc"].address == 0x0028
    assert [t[f"data{i}"].address for i in range(16)] == list(range(0x0008, 0x0028, 2))
    assert t["status"].access is Access.RO and t["status"].reset == 0x0006


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


def test_simulated_chips_are_built_from_the_same_tables():
    assert set(SimMT9F002().values) == {r.address for r in f002.TABLE}
    assert set(SimLepton35().values) == {r.address for r in lep.TABLE}
    assert SimMT9F002().peek("model_id") == 0x2E01
