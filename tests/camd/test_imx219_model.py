"""The IMX219's register table and parameter rules, against the reference facts."""

import pytest

from elphel_camd.errors import ParameterRangeError
from elphel_camd.frame_metadata import bayer_after_flips
from elphel_camd.params import WINDOW
from elphel_camd.sensors import IMX219
from elphel_camd.sensors import imx219 as spec
from elphel_camd.sensors import imx219_registers as regs
from elphel_camd.sensors.registers import Register, RegisterTable
from tests.camd.scripted_bus import ScriptedBus


@pytest.mark.parametrize(
    ("name", "address", "width", "reset"),
    [
        ("chip_id", 0x0000, 16, 0x0219),
        ("mode_select", 0x0100, 8, 0),
        ("analogue_gain", 0x0157, 8, 0),
        ("digital_gain", 0x0158, 16, 0x0100),
        ("coarse_integration_time", 0x015A, 16, None),
        ("frame_length_lines", 0x0160, 16, None),
        ("line_length_pck", 0x0162, 16, 3448),
        ("x_addr_start", 0x0164, 16, 0),
        ("x_addr_end", 0x0166, 16, 3279),
        ("y_addr_start", 0x0168, 16, 0),
        ("y_addr_end", 0x016A, 16, 2463),
        ("x_output_size", 0x016C, 16, 3280),
        ("y_output_size", 0x016E, 16, 2464),
        ("orientation", 0x0172, 8, 0),
        ("binning_mode_h", 0x0174, 8, 0),
        ("binning_mode_v", 0x0175, 8, 0),
        ("csi_data_format", 0x018C, 16, 0x0A0A),
    ],
)
def test_reference_addresses_widths_and_resets(name, address, width, reset):
    register = regs.TABLE[name]
    assert (register.address, register.width) == (address, width)
    if reset is not None:
        assert register.reset == reset
    assert regs.TABLE.address_bytes == 2


def test_limits_of_the_gain_registers():
    assert regs.TABLE["analogue_gain"].limit == 232
    digital = regs.TABLE["digital_gain"]
    assert (digital.minimum, digital.limit) == (0x0100, 0x0FFF)


def test_a_byte_claimed_by_two_registers_is_refused():
    table = RegisterTable(
        "X", [Register("a", 0x10, 0), Register("b", 0x11, 0, width=8)], address_bytes=2
    )
    with pytest.raises(ValueError, match="b and a share byte 0x0011"):
        regs.check_byte_layout(table)


def test_geometry_and_timing_facts():
    assert (regs.ACTIVE_WIDTH, regs.ACTIVE_HEIGHT, regs.PIXEL_PITCH_UM) == (3280, 2464, 1.12)
    assert (regs.ARRAY_WIDTH, regs.ARRAY_HEIGHT) == (3296, 2480)
    # 3.68 x 2.76 mm sensor (dissertation Table 3)
    assert pytest.approx(3.67, abs=0.01) == regs.ACTIVE_WIDTH * regs.PIXEL_PITCH_UM / 1000
    assert spec.row_time_s() == pytest.approx(3448 / 182.4e6)
    assert spec.row_time_s(line_length_pixels=1724, pixel_rate_hz=91.2e6) == spec.row_time_s()


@pytest.mark.parametrize(("code", "gain"), [(0, 1.0), (128, 2.0), (192, 4.0), (232, 256 / 24)])
def test_analogue_gain_code(code, gain):
    assert spec.analogue_gain(code) == pytest.approx(gain)
    assert spec.analogue_gain_code(gain) == code


def test_out_of_range_gain_codes_are_refused():
    with pytest.raises(ValueError, match=r"allowed 0\.\.232"):
        spec.analogue_gain(233)
    with pytest.raises(ValueError, match=r"allowed >= 1\.0"):
        spec.analogue_gain_code(0.5)


@pytest.mark.parametrize("gain", [1.0, 1.5, 2.0, 3.0, 7.3, 10.0, 12.0, 15.75])
def test_split_gain_puts_analogue_first_and_the_digital_rest_within_half_a_step(gain):
    code, digital = spec.split_gain(round(gain * 0x10000))
    assert spec.analogue_gain(code) <= gain + 1e-9
    assert spec.analogue_gain(min(code + 1, 232)) > gain or code == 232
    assert spec.total_gain(code, digital) == pytest.approx(gain, rel=0.5 / 256 * 1.01)


@pytest.mark.parametrize(("fliph", "flipv"), [(0, 0), (1, 0), (0, 1), (1, 1)])
def test_bayer_order_after_flips_is_the_reference_and_the_daemon_label(fliph, flipv):
    expected = {(0, 0): "RGGB", (1, 0): "GRBG", (0, 1): "GBRG", (1, 1): "BGGR"}[fliph, flipv]
    assert spec.bayer_order(fliph, flipv) == expected
    assert bayer_after_flips(regs.BAYER, fliph, flipv) == expected


def test_binning_halves_the_binned_axes():
    assert spec.binned_size(3280, 2464, binning_h=1, binning_v=3) == (1640, 1232)
    assert spec.binned_size(640, 480, binning_h=0, binning_v=1) == (640, 240)


def driver():
    return IMX219(IMX219.open_io(ScriptedBus([]), bus_name="port 0"))


def test_defaults_are_the_whole_array_at_10_ms_gain_one():
    s = driver().defaults()
    row_us = spec.row_time_s() * 1e6
    assert (s["WOI_WIDTH"], s["WOI_HEIGHT"], s["VEXPOS"]) == (3280, 2464, round(10_000 / row_us))
    assert s["EXPOS"] == round(s["VEXPOS"] * row_us)
    assert {s[g] for g in spec.GAIN_PARAMS} == {0x10000}
    assert s["FP1000S"] == round(1000 / ((2464 + 32) * spec.row_time_s()))


def test_one_gain_for_all_colours():
    d = driver()
    s = d.normalize({**d.defaults(), "GAINR": 0x20000}, frozenset({"GAINR"}))
    assert {s[g] for g in spec.GAIN_PARAMS} == {0x20000}
    both = {**d.defaults(), "GAINR": 0x20000, "GAINB": 0x30000}
    with pytest.raises(ParameterRangeError, match="one gain for all colours"):
        d.normalize(both, frozenset({"GAINR", "GAINB"}))
    assert d.actual_gains({**s, "GAING": 0x18000})["GAINB"] == round(1.5 * 0x10000 * 256 / 256.5)


def test_a_long_exposure_lengthens_the_frame_and_the_fps_limit_stretches_it():
    d = driver()
    long = d.normalize({**d.defaults(), "VEXPOS": 5000}, frozenset({"VEXPOS"}))
    assert spec.frame_lines(long) == 5004
    limited = d.normalize(
        {**d.defaults(), "FP1000SLIM": 5000, "FPSFLAGS": 1}, frozenset({"FP1000SLIM"})
    )
    assert spec.frame_lines(limited) == -(-200e-3 // spec.row_time_s())
    assert limited["FP1000S"] == 5000


def test_binning_halves_the_output_and_the_frame_at_the_same_line_time():
    d = driver()
    both = frozenset({"BIN_HOR", "BIN_VERT"})
    s = d.normalize({**d.defaults(), "BIN_HOR": 2, "BIN_VERT": 2}, both)
    written = d.registers(WINDOW, s)
    assert (written["x_output_size"], written["y_output_size"]) == (1640, 1232)
    assert (written["x_addr_end"], written["y_addr_end"]) == (3279, 2463)  # the whole array
    assert written["binning_mode_h"] == written["binning_mode_v"] == regs.BINNING_2X2
    assert spec.frame_lines(s) == 1232 + 32
    assert s["FP1000S"] == round(1000 / ((1232 + 32) * spec.row_time_s()))
    assert s["EXPOS"] == round(s["VEXPOS"] * spec.row_time_s() * 1e6)
    across = d.normalize({**d.defaults(), "BIN_HOR": 2}, frozenset({"BIN_HOR"}))
    written = d.registers(WINDOW, across)
    assert (written["x_output_size"], written["y_output_size"]) == (1640, 2464)
    assert (written["binning_mode_h"], written["binning_mode_v"]) == (regs.BINNING_2X2, 0)


@pytest.mark.parametrize(
    ("changes", "name", "allowed"),
    [
        ({"BIN_HOR": 3}, "BIN_HOR", "1..2"),
        ({"BIN_VERT": 2, "WOI_HEIGHT": 482}, "WOI_HEIGHT", "multiple of 4 while BIN_VERT=2"),
        ({"WOI_WIDTH": 3282}, "WOI_WIDTH", "2..3280"),
        ({"WOI_LEFT": 1, "WOI_WIDTH": 640}, "WOI_LEFT", "even"),
        ({"VEXPOS": 3}, "VEXPOS", "4..65531"),
        ({"TRIG": 4}, "TRIG", "no trigger input"),
        ({"GAING": 0x8000}, "GAING", "65536..1032192"),
        ({"FP1000SLIM": 100, "FPSFLAGS": 1}, "FP1000SLIM", "808.."),
        ({"FPSFLAGS": 3, "FP1000SLIM": 30000, "VEXPOS": 2600}, "EXPOS", "keeps the frame rate"),
    ],
)
def test_invalid_values_name_parameter_and_what_is_allowed(changes, name, allowed):
    d = driver()
    with pytest.raises(ParameterRangeError, match=name) as info:
        d.normalize({**d.defaults(), **changes}, frozenset(changes))
    assert allowed in str(info.value)
