"""Transcript tests: the exact I2C transfers of every MT9F002 driver operation."""

import errno

import pytest

from elphel_camd.errors import I2CError, ParameterRangeError
from elphel_camd.i2c import RegisterIO
from elphel_camd.params import EXPOSURE, GAINS, LIMITFPS, TRIGGERMODE, WINDOW
from elphel_camd.sensors import MT9F002, detect
from elphel_camd.sensors import mt9f002 as spec
from elphel_camd.sensors.registers import Access
from tests.camd.scripted_bus import ScriptedBus

A = 0x10  # the MT9F002's address


def read(register: int, value: int):
    return [("w", A, register.to_bytes(2, "big")), ("r", A, value.to_bytes(2, "big"))]


def write(register: int, value: int):
    return [("w", A, register.to_bytes(2, "big") + value.to_bytes(2, "big"))]


def driver(bus):
    """A driver whose shadows hold the reset values (as after init on a fresh chip)."""
    d = MT9F002(RegisterIO(bus, A, reg_bytes=2, bus_name="port 1"))
    d.shadow = {r.name: r.reset for r in spec.TABLE if r.access is not Access.WO}
    return d


def state(**changes):
    d = MT9F002(RegisterIO(ScriptedBus([]), A, reg_bytes=2))
    s = d.defaults()
    s.update(changes)
    return d.normalize(s, frozenset(changes))


def test_probe_reads_model_id_at_0x3000_and_needs_an_exact_match():
    bus = ScriptedBus([read(0x3000, 0x2E01)])
    assert isinstance(MT9F002.probe(bus, bus_name="port 1"), MT9F002)
    bus.done()
    bus = ScriptedBus([read(0x3000, 0x2E02)])
    assert MT9F002.probe(bus, bus_name="port 1") is None
    bus.done()


def test_detect_tries_mt9p006_first_then_finds_the_mt9f002():
    bus = ScriptedBus([errno.EREMOTEIO, errno.EREMOTEIO, read(0x3000, 0x2E01)])
    assert isinstance(detect(bus, bus_name="port 1"), MT9F002)
    bus.done()


def test_init_reads_every_register_then_writes_elphels_list():
    readable = [r for r in spec.TABLE if r.access is not Access.WO]
    script = [read(r.address, r.reset) for r in readable]
    script += [
        write(0x31C0, 0x8000),  # hispi_timing
        write(0x0306, 0x00B4),  # pll_multiplier
        write(0x31C6, 0x8400),  # hispi_control_status
        write(0x306E, 0x9280),  # datapath_select
        write(0x3028, 0x000A),  # analog gain code global
        write(0x302C, 0x000D),  # red
        write(0x302E, 0x0010),  # blue
        write(0x3012, 0x0100),  # coarse_integration_time
        write(0x3158, 0x2000),  # slave_mode
        write(0x3026, 0xFCFF),  # gpi_status
        write(0x301A, 0x011C),  # reset_register, last
    ]
    bus = ScriptedBus(script)
    d = MT9F002(RegisterIO(bus, A, reg_bytes=2))
    d.init()
    bus.done()
    assert d.shadow["pll_multiplier"] == 0xB4


def test_window_writes_addresses_and_output_sizes():
    bus = ScriptedBus(
        [
            write(0x3004, 144 + 1000),  # x_addr_start
            write(0x3008, 144 + 1000 + 127),  # x_addr_end
            write(0x3002, 32 + 800),  # y_addr_start
            write(0x3006, 32 + 800 + 95),  # y_addr_end
            write(0x034C, 128),  # x_output_size
            write(0x034E, 96),  # y_output_size
        ]
    )
    d = driver(bus)
    s = state(WOI_LEFT=1000, WOI_TOP=800, WOI_WIDTH=128, WOI_HEIGHT=96)
    assert d.program(WINDOW, s) == [
        "x_addr_start",
        "x_addr_end",
        "y_addr_start",
        "y_addr_end",
        "x_output_size",
        "y_output_size",
    ]
    assert d.program(WINDOW, s) == []  # nothing changed: nothing sent
    bus.done()


@pytest.mark.parametrize(
    ("fliph", "flipv", "mode"), [(1, 0, 0x4041), (0, 1, 0x8041), (1, 1, 0xC041)]
)
def test_flips_set_read_mode_bits_14_and_15(fliph, flipv, mode):
    bus = ScriptedBus([write(0x3040, mode)])
    d = driver(bus)
    s = state(FLIPH=fliph, FLIPV=flipv)
    assert d.program(WINDOW, s) == ["read_mode"]
    bus.done()


def test_photo_finish_reads_pf_height_rows():
    bus = ScriptedBus([write(0x3006, 32 + 2 - 1), write(0x034E, 2)])
    d = driver(bus)
    d.program(WINDOW, state(PF_HEIGHT=2, WOI_HEIGHT=16, WOI_TOP=0))
    bus.done()


def test_exposure_writes_coarse_integration_rows():
    # 128 wide: a row is 0x930 VT clocks at 220 MHz = 10.69 us; 2000 us = 187 rows.
    s = state(WOI_WIDTH=128, WOI_HEIGHT=96, EXPOS=2000)
    assert s["VEXPOS"] == 187 and s["EXPOS"] == round(187 * 0x930 / 220)
    bus = ScriptedBus([write(0x3012, 187)])
    driver(bus).program(EXPOSURE, s)
    bus.done()


def test_wide_outputs_count_the_row_twice():
    # 912 wide and more: line_length_pck 0x4C8, a row of 2 x 0x4C8 VT clocks (11.13 us).
    s = state(WOI_WIDTH=912, WOI_HEIGHT=96, EXPOS=2000)
    assert s["VEXPOS"] == round(2000 / (2 * 0x4C8 / 220))
    bus = ScriptedBus([write(0x300C, 0x4C8), write(0x300A, 96 + 146)])
    driver(bus).program(LIMITFPS, s)
    bus.done()


def test_limitfps_writes_line_length_and_frame_length():
    s = state(WOI_WIDTH=128, WOI_HEIGHT=96, EXPOS=2000)
    bus = ScriptedBus([write(0x300C, 0x0930), write(0x300A, 96 + 146)])
    driver(bus).program(LIMITFPS, s)
    bus.done()
    # A long exposure lengthens the frame to exposure + 1 rows.
    s = state(WOI_WIDTH=128, WOI_HEIGHT=96, EXPOS=50_000)
    bus = ScriptedBus([write(0x300C, 0x0930), write(0x300A, s["VEXPOS"] + 1)])
    driver(bus).program(LIMITFPS, s)
    bus.done()
    # An fps limit stretches it: 10 fps = 0.1 s / 10.69 us = 9354 rows.
    s = state(WOI_WIDTH=128, WOI_HEIGHT=96, EXPOS=2000, FP1000SLIM=10_000, FPSFLAGS=1)
    bus = ScriptedBus([write(0x300C, 0x0930), write(0x300A, 9354)])
    driver(bus).program(LIMITFPS, s)
    bus.done()
    assert s["FP1000S"] == 10_000


def test_triggered_frame_length_is_the_trigger_period_minus_one_row():
    s = state(WOI_WIDTH=128, WOI_HEIGHT=96, EXPOS=1000, TRIG=4, TRIG_PERIOD=2_000_000)
    lines = 2_000_000 * 220 // 100 // 0x930 - 1
    bus = ScriptedBus([write(0x300C, 0x0930), write(0x300A, lines)])
    driver(bus).program(LIMITFPS, s)
    bus.done()


@pytest.mark.parametrize(("trig", "mode"), [(4, 0xA000), (20, 0xA000)])
def test_trigger_mode_writes_slave_mode(trig, mode):
    bus = ScriptedBus([write(0x3158, mode), write(0x3158, 0x2000)])
    d = driver(bus)
    d.program(TRIGGERMODE, state(TRIG=trig))
    d.program(TRIGGERMODE, state(TRIG=0))
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
def test_gain_codes(gain, code):
    assert spec.encode_gain(gain) == code
    assert spec.decode_gain(code) * 0x10000 == gain


def test_gains_write_each_colour_register():
    s = state(GAINR=0x20000, GAING=0x30000, GAINGB=0x80000, GAINB=0xFE000)
    bus = ScriptedBus(
        [
            write(0x305A, 0x1440),  # red
            write(0x3056, 0x1830),  # green1 (red rows)
            write(0x305C, 0x1C40),  # green2 (blue rows)
            write(0x3058, 0x1C7F),  # blue
        ]
    )
    d = driver(bus)
    d.program(GAINS, s)
    bus.done()
    assert d.actual_gains(state(GAINR=0x2_2345))["GAINR"] == 0x2_2000


def test_raw_register_read_and_write():
    bus = ScriptedBus([read(0x3040, 0x0041), write(0x3070, 0x0002)])
    d = driver(bus)
    assert d.read("read_mode") == 0x0041
    d.write("test_pattern_mode", 2)
    bus.done()
    with pytest.raises(ValueError, match="read-only"):
        d.write("model_id", 1)


def test_failed_write_is_read_back_and_named():
    bus = ScriptedBus([errno.EREMOTEIO, errno.EREMOTEIO, errno.EREMOTEIO, read(0x3012, 0x0010)])
    d = driver(bus)
    d.io.retries = 2
    with pytest.raises(I2CError) as info:
        d.write("coarse_integration_time", 100)
    assert (info.value.address, info.value.register) == (0x10, 0x3012)
    assert d.shadow["coarse_integration_time"] == 0x0010
    bus.done()


def test_out_of_range_values_are_refused_before_any_transfer():
    with pytest.raises(ParameterRangeError, match=r"2\.\.4384 \(even\)"):
        state(WOI_WIDTH=4386)
    with pytest.raises(ParameterRangeError, match="98304"):
        state(GAINR=0x10000)
    with pytest.raises(ParameterRangeError, match=r"1\.\.65534"):
        state(VEXPOS=0x10000)
