"""Meta-test: every declared bit field, and every field a driver or a simulated chip uses.

Fields are declared next to their registers and reached only by name
(`RegisterTable.field("register.field")`), so a field a driver or a chip uses must be
declared; this test walks the tables, the drivers' parameter -> field rules, the
simulated chips' fields and every field name written in the sources.
"""

import re
from pathlib import Path

import pytest

import elphel_camd.sensors
import elphel_sim.chips
from elphel_camd.params import PARAMS, TRIG_SNAPSHOT
from elphel_camd.sensors import DRIVERS, MT9F002, MT9P006, RegisterFileSensor, cci
from elphel_camd.sensors.registers import Field, FieldRule, FieldRules, Register, RegisterTable
from elphel_sim.chips.aptina import SimAptinaChip
from elphel_sim.chips.mt9f002 import SimMT9F002
from elphel_sim.chips.mt9p006 import SimMT9P006

TABLES = [d.table for d in DRIVERS if issubclass(d, RegisterFileSensor)] + [cci.REGISTERS]
SIM_APTINA = [SimMT9P006, SimMT9F002]


@pytest.mark.parametrize("table", TABLES, ids=lambda t: t.model)
def test_every_field_fits_its_register_and_no_two_share_a_bit(table):
    for register in table:
        used = 0
        names = set()
        for f in register.fields:
            assert 0 <= f.shift <= f.msb < register.width, f"{register.name}.{f.name}"
            assert not used & f.mask, f"{register.name}.{f.name} overlaps"
            assert f.name not in names
            used |= f.mask
            names.add(f.name)
            bound = table.field(f"{register.name}.{f.name}")
            assert bound.register is register and bound.field is f
            assert bound.reset == (register.reset & f.mask) >> f.shift
        # Decoding the reset value into fields and putting them back gives its field bits.
        word = 0
        for name, value in table.fields_of(register.name, register.reset).items():
            word = table.field(f"{register.name}.{name}").put(word, value)
        assert word == register.reset & used


@pytest.mark.parametrize("table", TABLES, ids=lambda t: t.model)
def test_every_field_is_named_and_documented_through_its_register(table):
    fields = list(table.fields())
    assert len({b.name for b in fields}) == len(fields)
    for bound in fields:
        assert bound.register.doc
        assert re.fullmatch(r"[a-z0-9_]+\.[a-z0-9_]+", bound.name), bound.name


def test_tables_reject_bad_fields():
    with pytest.raises(ValueError, match="does not fit the 8-bit register"):
        RegisterTable("X", [Register("a", 1, 0, width=8, fields=(Field("f", 8),))], address_bytes=1)
    with pytest.raises(ValueError, match="overlaps another field of a"):
        fields = (Field("f", 3, 0), Field("g", 4, 3))
        RegisterTable("X", [Register("a", 1, 0, fields=fields)], address_bytes=1)
    with pytest.raises(ValueError, match=r"a\.f \(bits 3\) declared twice"):
        fields = (Field("f", 2), Field("f", 3))
        RegisterTable("X", [Register("a", 1, 0, fields=fields)], address_bytes=1)
    with pytest.raises(ValueError, match=r"lsb must be 0\.\.msb"):
        RegisterTable("X", [Register("a", 1, 0, fields=(Field("f", 2, 5),))], address_bytes=1)


def test_field_lookup_by_name_is_the_only_way_and_names_what_exists():
    table = MT9P006.table
    with pytest.raises(KeyError, match=r"MT9P006 has no field 'read_mode_2\.mirror'"):
        table.field("read_mode_2.mirror")
    bound = table.field("read_mode_2.mirror_column")
    assert (bound.field.shift, bound.field.width, bound.field.mask) == (14, 1, 0x4000)
    assert bound.put(0x0040, 1) == 0x4040 and bound.get(0xC040) == 1
    with pytest.raises(ValueError, match=r"read_mode_2\.mirror_column \(bits 14\) = 2; allowed"):
        bound.put(0, 2)


@pytest.mark.parametrize(
    ("driver", "register", "value", "fields"),
    [
        (MT9P006, "read_mode_2", 0xC040, {"mirror_column": 1, "mirror_row": 1, "row_blc": 1}),
        (
            MT9P006,
            "read_mode_1",
            0x4186,
            {"snapshot": 1, "global_reset": 1, "strobe_end": 2, "strobe_start": 1},
        ),
        (MT9P006, "red_gain", 0x0860, {"analog": 32, "x2": 1, "digital": 8}),
        (MT9F002, "read_mode", 0x4041, {"flip_horizontal": 1, "x_odd_inc": 1, "y_odd_inc": 1}),
        (MT9F002, "red_gain", 0x1C7F, {"analog2": 127, "colamp": 3, "digital": 1}),
        (MT9F002, "slave_mode", 0xA000, {"triggered": 1}),
        (MT9F002, "model_id", 0x2E01, {}),
    ],
    ids=lambda v: v.model if isinstance(v, type) else None,
)
def test_fields_of_decodes_a_register_value(driver, register, value, fields):
    decoded = driver.table.fields_of(register, value)
    assert {k: v for k, v in decoded.items() if v} == {k: v for k, v in fields.items() if v}
    assert set(fields) <= set(decoded)


@pytest.mark.parametrize("driver", [MT9P006, MT9F002], ids=lambda d: d.model)
def test_every_rule_names_a_declared_field_and_a_writable_parameter(driver):
    rules: FieldRules = driver.rules
    assert rules.table is driver.table
    assert list(rules), f"{driver.model} declares no field rules"
    for rule in rules:
        bound = driver.table.field(rule.field)
        assert rule.parameter in driver.writable and rule.parameter in PARAMS
        if rule.mask is not None:
            assert bound.field.width == 1, rule
        else:
            assert PARAMS[rule.parameter].maximum <= bound.field.limit, rule
    assert rules.functions <= set(driver.ahead)


def test_rules_refuse_undeclared_fields():
    with pytest.raises(KeyError, match=r"no field 'read_mode_2\.flip'"):
        FieldRules(MT9P006.table, [FieldRule("window", "FLIPH", "read_mode_2.flip")])


@pytest.mark.parametrize(
    ("chip", "driver"), [(SimMT9P006, MT9P006), (SimMT9F002, MT9F002)], ids=["MT9P006", "MT9F002"]
)
def test_simulated_chips_decode_the_fields_the_driver_writes(chip, driver):
    assert issubclass(chip, SimAptinaChip) and chip.register_table is driver.table
    written = {(rule.parameter, rule.mask): rule.field for rule in driver.rules}
    assert chip.fliph_field == written["FLIPH", None]
    assert chip.flipv_field == written["FLIPV", None]
    assert chip.snapshot_field == written["TRIG", TRIG_SNAPSHOT]


def _sources():
    for package in (elphel_camd.sensors, elphel_sim.chips):
        yield from Path(package.__file__).parent.glob("*.py")


def test_every_field_named_in_the_sources_is_declared():
    declared = {b.name for table in TABLES for b in table.fields()}
    named = set()
    pattern = re.compile(r"""["']([a-z][a-z0-9_]*\.[a-z][a-z0-9_]*)["']""")
    for path in _sources():
        for name in pattern.findall(path.read_text()):
            if name.split(".")[0] in {r.name for table in TABLES for r in table}:
                named.add(name)
                assert name in declared, f"{path.name}: field {name!r} is not declared"
    # The drivers' rules, the chips' flips / trigger / reset bits and the gain layouts.
    assert {"read_mode_2.mirror_column", "slave_mode.triggered", "status.error"} <= named
    assert {"green1_gain.analog", "green1_gain.analog2", "restart.restart"} <= named
