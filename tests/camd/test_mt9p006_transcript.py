"""Transcript tests of every MT9P006 driver operation: the exact I2C bytes it sends."""

import pytest

from elphel_camd.i2c import RegisterIO
from elphel_camd.params import EXPOSURE, GAINS, LIMITFPS, TRIGGERMODE, WINDOW
from elphel_camd.sensors import MT9P006
from elphel_camd.sensors import mt9p006 as spec
from elphel_camd.sensors.registers import Access
from tests.camd.scripted_bus import ScriptedBus

A = 0x48


def write(register: int, value: int):
    return [("w", A, bytes([register]) + value.to_bytes(2, "big"))]


def read(register: int, value: int):
    return [("w", A, bytes([register])), ("r", A, value.to_bytes(2, "big"))]


def driver(bus):
    """A driver whose shadows hold the reset values (as after init on a fresh chip)."""
    d = MT9P006(RegisterIO(bus, A, reg_bytes=1, bus_name="port 0"))
    d.shadow = {r.name: r.reset for r in spec.TABLE if r.access is not Access.WO}
    return d


def state(**changes):
    d = MT9P006(RegisterIO(ScriptedBus([]), A, reg_bytes=1))
    s = d.defaults()
    s.update(changes)
    return d.normalize(s, frozenset(changes))


def test_init_reads_every_register_then_writes_only_what_differs():
    # A chip left with output control and register 0x7F changed by someone else.
    found = {0x07: 0x1F80, 0x7F: 0x0004}
    readable = [r for r in spec.TABLE if r.access is not Access.WO]
    script = [read(r.address, found.get(r.address, r.reset)) for r in readable]
    script += [write(0x07, 0x1F82), write(0x7F, 0x0000)]
    bus = ScriptedBus(script)
    d = MT9P006(RegisterIO(bus, A, reg_bytes=1))
    d.init()
    bus.done()
    assert d.shadow["output_control"] == 0x1F82


def test_window_writes_start_and_size_registers():
    bus = ScriptedBus(
        [
            write(0x01, 50 + 800),  # row_start = clear top + WOI_TOP
            write(0x02, 10 + 1000),  # column_start = clear left + WOI_LEFT
            write(0x03, 95),  # rows - 1
            write(0x04, 127),  # columns - 1
        ]
    )
    d = driver(bus)
    d.program(WINDOW, state(WOI_LEFT=1000, WOI_TOP=800, WOI_WIDTH=128, WOI_HEIGHT=96))
    bus.done()


@pytest.mark.parametrize(
    ("fliph", "flipv", "mode"), [(1, 0, 0x4040), (0, 1, 0x8040), (1, 1, 0xC040)]
)
def test_flips_set_read_mode_2_bits_14_and_15(fliph, flipv, mode):
    bus = ScriptedBus([write(0x01, 50), write(0x02, 10), write(0x20, mode)])
    driver(bus).program(WINDOW, state(FLIPH=fliph, FLIPV=flipv))
    bus.done()


def test_exposure_splits_shutter_rows_across_two_registers():
    s = state(WOI_WIDTH=2592, EXPOS=4_000_000)  # 4 s: more than 16 bits of rows
    rows = s["VEXPOS"]
    assert rows > 0xFFFF
    bus = ScriptedBus([write(0x08, rows >> 16), write(0x09, rows & 0xFFFF)])
    driver(bus).program(EXPOSURE, s)
    bus.done()
    assert rows == round(4_000_000 / ((2592 + 900) / 96))


def test_gains_write_analog_codes_with_the_x2_stage_above_394():
    s = state(GAINR=0x20000, GAING=0x10000, GAINGB=0x18000, GAINB=0x80000)
    bus = ScriptedBus(
        [
            write(0x2D, 16),  # red 2.0x: code gain*8
            write(0x2E, 12),  # green2 1.5x
            write(0x2C, 0x40 | 32),  # blue 8.0x: x2 stage on, code gain*4
        ]
    )
    driver(bus).program(GAINS, s)  # green1 stays 1.0x = reset code 8: not written
    bus.done()


@pytest.mark.parametrize(("trig", "mode"), [(4, 0x4106), (20, 0x4186)])
def test_trigger_mode_sets_snapshot_and_grr_bits(trig, mode):
    bus = ScriptedBus([write(0x1E, mode)])
    driver(bus).program(TRIGGERMODE, state(TRIG=trig))
    bus.done()


def test_fps_limit_writes_blanking():
    s = state(WOI_WIDTH=128, WOI_HEIGHT=96, EXPOS=100, FP1000SLIM=50_000, FPSFLAGS=1)
    row_s = (128 + 900) / 96e6
    blank = -(-0.02 // row_s) - 96  # ceil(period / row) - rows
    bus = ScriptedBus([write(0x05, 450), write(0x06, int(blank))])
    driver(bus).program(LIMITFPS, s)
    bus.done()


def test_unchanged_registers_are_not_written_again():
    bus = ScriptedBus([write(0x2D, 16)])
    d = driver(bus)
    s = state(GAINR=0x20000)
    d.program(GAINS, s)
    d.program(GAINS, s)  # the shadow already holds these values
    bus.done()
