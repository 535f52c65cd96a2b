"""Register tables check themselves; the MT9P006 table matches the reference facts."""

import pytest

from elphel_camd.sensors import DRIVERS
from elphel_camd.sensors.mt9p006 import TABLE, decode_gain
from elphel_camd.sensors.registers import Access, Register, RegisterTable


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
        TABLE["row_start"].check(3000)


def test_every_driver_table_is_consistent():
    for driver in DRIVERS:
        table = driver.table
        assert driver.chip_id_register in table
        chip = table[driver.chip_id_register]
        assert chip.access is Access.RO and chip.reset == driver.chip_id
        for r in table:
            assert r.doc, f"{driver.model} {r.name} has no doc"


def test_mt9p006_reference_values():
    assert TABLE["chip_version"].address == 0x00
    assert TABLE["shutter_width_lower"].reset == 0x0797
    assert TABLE["read_mode_2"].address == 0x20
    assert TABLE["global_gain"].address == 0x35


@pytest.mark.parametrize(
    ("code", "gain"), [(0x0008, 1.0), (0x0010, 2.0), (0x0060, 8.0), (0x0860, 16.0), (0x007F, 15.75)]
)
def test_mt9p006_gain_code(code, gain):
    assert decode_gain(code) == pytest.approx(gain)
