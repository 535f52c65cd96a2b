"""Transcript tests of every MT9P006 and MT9F002 driver operation: the exact I2C bytes.

What both sensors do is parametrised over them; what only one does (the MT9P006's split
shutter width, the MT9F002's line length and trigger-period frame length) is tested on
that one.
"""

import errno
from dataclasses import dataclass

import pytest

from elphel_camd.errors import I2CError, ParameterRangeError
from elphel_camd.i2c import RegisterIO
from elphel_camd.params import EXPOSURE, GAINS, LIMITFPS, TRIGGERMODE, WINDOW
from elphel_camd.sensors import MT9F002, MT9P006, detect
from elphel_camd.sensors import mt9f002 as f002
from elphel_camd.sensors.registers import Access
from tests.camd.scripted_bus import ScriptedBus


@dataclass(frozen=True)
class Chip:
    driver: type
    address: int
    reg_bytes: int
    bus_name: str

    def read(self, register: int, value: int):
        addr = register.to_bytes(self.reg_bytes, "big")
        return [("w", self.address, addr), ("r", self.address, value.to_bytes(2, "big"))]

    def write(self, register: int, value: int):
        data = register.to_bytes(self.reg_bytes, "big") + value.to_bytes(2, "big")
        return [("w", self.address, data)]

    def script(self, writes):
        return [self.write(register, value) for register, value in writes]

    def fresh(self, bus):
        """A driver whose shadows hold the reset values (as after init on a fresh chip)."""
        d = self.driver(
            RegisterIO(bus, self.address, reg_bytes=self.reg_bytes, bus_name=self.bus_name)
        )
        d.shadow = {r.name: r.reset for r in self.driver.table if r.access is not Access.WO}
        return d

    def state(self, **changes):
        d = self.driver(RegisterIO(ScriptedBus([]), self.address, reg_bytes=self.reg_bytes))
        s = d.defaults()
        s.update(changes)
        return d.normalize(s, frozenset(changes))


P006 = Chip(MT9P006, 0x48, 1, "port 0")
F002 = Chip(MT9F002, 0x10, 2, "port 1")
CHIPS = {"MT9P006": P006, "MT9F002": F002}


def chip_id(value):
    return value.driver.model if isinstance(value, Chip) else None


# -- both sensors ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("chip", "found", "writes", "shadow"),
    [
        # A chip left with output control and register 0x7F changed by someone else: only
        # what differs from Elphel's init list is written.
        (
            P006,
            {0x07: 0x1F80, 0x7F: 0x0004},
            [(0x07, 0x1F82), (0x7F, 0x0000)],
            ("output_control", 0x1F82),
        ),
        # The MT9F002 writes Elphel's whole list, whatever it read.
        (
            F002,
            {},
            [
                (0x31C0, 0x8000),  # hispi_timing
                (0x0306, 0x00B4),  # pll_multiplier
                (0x31C6, 0x8400),  # hispi_control_status
                (0x306E, 0x9280),  # datapath_select
                (0x3028, 0x000A),  # analog gain code global
                (0x302C, 0x000D),  # red
                (0x302E, 0x0010),  # blue
                (0x3012, 0x0100),  # coarse_integration_time
                (0x3158, 0x2000),  # slave_mode
                (0x3026, 0xFCFF),  # gpi_status
                (0x301A, 0x011C),  # reset_register, last
            ],
            ("pll_multiplier", 0xB4),
        ),
    ],
    ids=chip_id,
)
def test_init_reads_every_register_then_writes_elphels_list(chip, found, writes, shadow):
    readable = [r for r in chip.driver.table if r.access is not Access.WO]
    script = [chip.read(r.address, found.get(r.address, r.reset)) for r in readable]
    bus = ScriptedBus(script + chip.script(writes))
    d = chip.driver(RegisterIO(bus, chip.address, reg_bytes=chip.reg_bytes))
    d.init()
    bus.done()
    name, value = shadow
    assert d.shadow[name] == value


@pytest.mark.parametrize(
    ("chip", "writes"),
    [
        (
            P006,
            [
                ("row_start", 0x01, 50 + 800),  # clear top + WOI_TOP
                ("column_start", 0x02, 10 + 1000),  # clear left + WOI_LEFT
                ("row_size", 0x03, 95),  # rows - 1
                ("column_size", 0x04, 127),  # columns - 1
            ],
        ),
        (
            F002,
            [
                ("x_addr_start", 0x3004, 144 + 1000),
                ("x_addr_end", 0x3008, 144 + 1000 + 127),
                ("y_addr_start", 0x3002, 32 + 800),
                ("y_addr_end", 0x3006, 32 + 800 + 95),
                ("x_output_size", 0x034C, 128),
                ("y_output_size", 0x034E, 96),
            ],
        ),
    ],
    ids=chip_id,
)
def test_window_writes_start_and_size_registers(chip, writes):
    bus = ScriptedBus(chip.script([(register, value) for _, register, value in writes]))
    d = chip.fresh(bus)
    s = chip.state(WOI_LEFT=1000, WOI_TOP=800, WOI_WIDTH=128, WOI_HEIGHT=96)
    assert d.program(WINDOW, s) == [name for name, _, _ in writes]
    assert d.program(WINDOW, s) == []  # nothing changed: nothing sent
    bus.done()


@pytest.mark.parametrize(
    ("chip", "fliph", "flipv", "writes"),
    [
        # MT9P006: read mode 2 bits 14 and 15 (the default window moves to Elphel's origin).
        (P006, 1, 0, [(0x01, 50), (0x02, 10), (0x20, 0x4040)]),
        (P006, 0, 1, [(0x01, 50), (0x02, 10), (0x20, 0x8040)]),
        (P006, 1, 1, [(0x01, 50), (0x02, 10), (0x20, 0xC040)]),
        # MT9F002: read_mode bits 14 and 15.
        (F002, 1, 0, [(0x3040, 0x4041)]),
        (F002, 0, 1, [(0x3040, 0x8041)]),
        (F002, 1, 1, [(0x3040, 0xC041)]),
    ],
    ids=chip_id,
)
def test_flips_set_read_mode_bits_14_and_15(chip, fliph, flipv, writes):
    bus = ScriptedBus(chip.script(writes))
    d = chip.fresh(bus)
    written = d.program(WINDOW, chip.state(FLIPH=fliph, FLIPV=flipv))
    assert written[-1] == ("read_mode_2" if chip is P006 else "read_mode")
    bus.done()


@pytest.mark.parametrize(
    ("chip", "writes"),
    [
        (
            P006,
            [
                (0x2D, 16),  # red 2.0x: code gain*8
                (0x2E, 12),  # green2 1.5x
                (0x2C, 0x40 | 32),  # blue 8.0x: x2 stage on, code gain*4
            ],  # green1 stays 1.0x = reset code 8: not written
        ),
        (
            F002,
            [
                (0x305A, 0x1440),  # red 2.0x: colamp 1, analog2 64
                (0x3056, 0x1830),  # green1 (red rows) 3.0x: colamp 2, analog2 48
                (0x305C, 0x1C40),  # green2 (blue rows) 8.0x: colamp 3, analog2 64
                (0x3058, 0x1C7F),  # blue 15.875x
            ],
        ),
    ],
    ids=chip_id,
)
def test_gains_write_each_colour_register(chip, writes):
    gains = {
        P006: {"GAINR": 0x20000, "GAING": 0x10000, "GAINGB": 0x18000, "GAINB": 0x80000},
        F002: {"GAINR": 0x20000, "GAING": 0x30000, "GAINGB": 0x80000, "GAINB": 0xFE000},
    }[chip]
    bus = ScriptedBus(chip.script(writes))
    chip.fresh(bus).program(GAINS, chip.state(**gains))
    bus.done()


@pytest.mark.parametrize(
    ("chip", "requested", "actual"),
    [(P006, 0x2_2345, 0x2_2000), (F002, 0x2_2345, 0x2_2000), (P006, 0x5_1000, 0x5_0000)],
    ids=chip_id,
)
def test_actual_gains_are_what_the_code_gives(chip, requested, actual):
    d = chip.fresh(ScriptedBus([]))
    assert d.actual_gains(chip.state(GAINR=requested))["GAINR"] == actual


@pytest.mark.parametrize(
    ("chip", "trig", "writes"),
    [
        # MT9P006: read mode 1 bit 8 (snapshot) and bit 7 (global reset release).
        (P006, 4, [(0x1E, 0x4106), (0x1E, 0x4006)]),
        (P006, 20, [(0x1E, 0x4186), (0x1E, 0x4006)]),
        # MT9F002: slave_mode 0xA000 when triggered, 0x2000 free-running.
        (F002, 4, [(0x3158, 0xA000), (0x3158, 0x2000)]),
        (F002, 20, [(0x3158, 0xA000), (0x3158, 0x2000)]),
    ],
    ids=chip_id,
)
def test_trigger_mode_sets_snapshot_and_back(chip, trig, writes):
    bus = ScriptedBus(chip.script(writes))
    d = chip.fresh(bus)
    d.program(TRIGGERMODE, chip.state(TRIG=trig))
    d.program(TRIGGERMODE, chip.state(TRIG=0))
    bus.done()


@pytest.mark.parametrize("chip", [P006, F002], ids=chip_id)
def test_unchanged_registers_are_not_written_again(chip):
    register = 0x2D if chip is P006 else 0x305A
    bus = ScriptedBus([chip.write(register, chip.driver.encode_gain(0x20000))])
    d = chip.fresh(bus)
    s = chip.state(GAINR=0x20000)
    d.program(GAINS, s)
    d.program(GAINS, s)  # the shadow already holds these values
    bus.done()


@pytest.mark.parametrize(
    ("chip", "readable", "value", "writable", "read_only"),
    [
        (P006, ("read_mode_2", 0x20), 0x0040, ("test_pattern", 0xA0), "chip_version"),
        (F002, ("read_mode", 0x3040), 0x0041, ("test_pattern_mode", 0x3070), "model_id"),
    ],
    ids=chip_id,
)
def test_raw_register_read_and_write(chip, readable, value, writable, read_only):
    bus = ScriptedBus([chip.read(readable[1], value), chip.write(writable[1], 0x0002)])
    d = chip.fresh(bus)
    assert d.read(readable[0]) == value
    d.write(writable[0], 2)
    bus.done()
    with pytest.raises(ValueError, match="read-only"):
        d.write(read_only, 1)


@pytest.mark.parametrize(
    ("chip", "name", "register", "reset"),
    [
        (P006, "shutter_width_lower", 0x09, 0x0797),
        (F002, "coarse_integration_time", 0x3012, 0x0010),
    ],
    ids=chip_id,
)
def test_failed_write_is_read_back_and_named(chip, name, register, reset):
    bus = ScriptedBus(
        [errno.EREMOTEIO, errno.EREMOTEIO, errno.EREMOTEIO, chip.read(register, reset)]
    )
    d = chip.fresh(bus)
    d.io.retries = 2
    with pytest.raises(I2CError) as info:
        d.write(name, 100)
    assert (info.value.address, info.value.register) == (chip.address, register)
    assert d.shadow[name] == reset
    bus.done()


# -- MT9P006 only ----------------------------------------------------------------------------


def test_mt9p006_exposure_splits_shutter_rows_across_two_registers():
    s = P006.state(WOI_WIDTH=2592, EXPOS=4_000_000)  # 4 s: more than 16 bits of rows
    rows = s["VEXPOS"]
    assert rows > 0xFFFF
    bus = ScriptedBus(P006.script([(0x08, rows >> 16), (0x09, rows & 0xFFFF)]))
    P006.fresh(bus).program(EXPOSURE, s)
    bus.done()
    assert rows == round(4_000_000 / ((2592 + 900) / 96))


def test_mt9p006_fps_limit_writes_blanking():
    s = P006.state(WOI_WIDTH=128, WOI_HEIGHT=96, EXPOS=100, FP1000SLIM=50_000, FPSFLAGS=1)
    row_s = (128 + 900) / 96e6
    blank = -(-0.02 // row_s) - 96  # ceil(period / row) - rows
    bus = ScriptedBus(P006.script([(0x05, 450), (0x06, int(blank))]))
    P006.fresh(bus).program(LIMITFPS, s)
    bus.done()


# -- MT9F002 only ----------------------------------------------------------------------------


def test_mt9f002_probe_reads_model_id_at_0x3000_and_needs_an_exact_match():
    bus = ScriptedBus([F002.read(0x3000, 0x2E01)])
    assert isinstance(MT9F002.probe(bus, bus_name="port 1"), MT9F002)
    bus.done()
    bus = ScriptedBus([F002.read(0x3000, 0x2E02)])
    assert MT9F002.probe(bus, bus_name="port 1") is None
    bus.done()


def test_detect_tries_mt9p006_first_then_finds_the_mt9f002():
    bus = ScriptedBus([errno.EREMOTEIO, errno.EREMOTEIO, F002.read(0x3000, 0x2E01)])
    assert isinstance(detect(bus, bus_name="port 1"), MT9F002)
    bus.done()


def test_mt9f002_photo_finish_reads_pf_height_rows():
    bus = ScriptedBus(F002.script([(0x3006, 32 + 2 - 1), (0x034E, 2)]))
    F002.fresh(bus).program(WINDOW, F002.state(PF_HEIGHT=2, WOI_HEIGHT=16, WOI_TOP=0))
    bus.done()


def test_mt9f002_exposure_writes_coarse_integration_rows():
    # 128 wide: a row is 0x930 VT clocks at 220 MHz = 10.69 us; 2000 us = 187 rows.
    s = F002.state(WOI_WIDTH=128, WOI_HEIGHT=96, EXPOS=2000)
    assert s["VEXPOS"] == 187 and s["EXPOS"] == round(187 * 0x930 / 220)
    bus = ScriptedBus(F002.script([(0x3012, 187)]))
    F002.fresh(bus).program(EXPOSURE, s)
    bus.done()


def test_mt9f002_wide_outputs_count_the_row_twice():
    # 912 wide and more: line_length_pck 0x4C8, a row of 2 x 0x4C8 VT clocks (11.13 us).
    s = F002.state(WOI_WIDTH=912, WOI_HEIGHT=96, EXPOS=2000)
    assert s["VEXPOS"] == round(2000 / (2 * 0x4C8 / 220))
    bus = ScriptedBus(F002.script([(0x300C, 0x4C8), (0x300A, 96 + 146)]))
    F002.fresh(bus).program(LIMITFPS, s)
    bus.done()


def test_mt9f002_limitfps_writes_line_length_and_frame_length():
    s = F002.state(WOI_WIDTH=128, WOI_HEIGHT=96, EXPOS=2000)
    bus = ScriptedBus(F002.script([(0x300C, 0x0930), (0x300A, 96 + 146)]))
    F002.fresh(bus).program(LIMITFPS, s)
    bus.done()
    # A long exposure lengthens the frame to exposure + 1 rows.
    s = F002.state(WOI_WIDTH=128, WOI_HEIGHT=96, EXPOS=50_000)
    bus = ScriptedBus(F002.script([(0x300C, 0x0930), (0x300A, s["VEXPOS"] + 1)]))
    F002.fresh(bus).program(LIMITFPS, s)
    bus.done()
    # An fps limit stretches it: 10 fps = 0.1 s / 10.69 us = 9354 rows.
    s = F002.state(WOI_WIDTH=128, WOI_HEIGHT=96, EXPOS=2000, FP1000SLIM=10_000, FPSFLAGS=1)
    bus = ScriptedBus(F002.script([(0x300C, 0x0930), (0x300A, 9354)]))
    F002.fresh(bus).program(LIMITFPS, s)
    bus.done()
    assert s["FP1000S"] == 10_000


def test_mt9f002_triggered_frame_length_is_the_trigger_period_minus_one_row():
    s = F002.state(WOI_WIDTH=128, WOI_HEIGHT=96, EXPOS=1000, TRIG=4, TRIG_PERIOD=2_000_000)
    lines = 2_000_000 * 220 // 100 // 0x930 - 1
    bus = ScriptedBus(F002.script([(0x300C, 0x0930), (0x300A, lines)]))
    F002.fresh(bus).program(LIMITFPS, s)
    bus.done()


@pytest.mark.parametrize(
    ("gain", "code"),
    [
        (0x18000, 0x1430),  # 1.5x: colamp 1 (x2), analog2 48/64
        (0x20000, 0x1440),  # 2.0x: colamp 1, analog2 64
        (0x30000, 0x1830),  # 3.0x: colamp 2 (x4), analog2 48
        (0x80000, 0x1C40),  # 8.0x: colamp 3 (x8), analog2 64
        (0xFE000, 0x1C7F),  # 15.875x, the largest
    ],
)
def test_mt9f002_gain_codes(gain, code):
    assert f002.encode_gain(gain) == code
    assert f002.decode_gain(code) * 0x10000 == gain


def test_mt9f002_out_of_range_values_are_refused_before_any_transfer():
    with pytest.raises(ParameterRangeError, match=r"2\.\.4384 \(even\)"):
        F002.state(WOI_WIDTH=4386)
    with pytest.raises(ParameterRangeError, match="98304"):
        F002.state(GAINR=0x10000)
    with pytest.raises(ParameterRangeError, match=r"1\.\.65534"):
        F002.state(VEXPOS=0x10000)
