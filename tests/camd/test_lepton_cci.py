"""Transcript tests: the exact CCI transfers of every Lepton 3.5 driver operation."""

import errno

import pytest

from elphel_camd.errors import I2CError, LeptonError
from elphel_camd.i2c import RegisterIO
from elphel_camd.params import EXPOSURE, WINDOW
from elphel_camd.sensors import (
    CommandSensor,
    Lepton35,
    RegisterFileSensor,
    cci,
    detect,
    register_file,
)
from tests.camd.scripted_bus import ScriptedBus

A = 0x2A  # the Lepton's address
READY = 0x0006  # booted (bits 1, 2), not busy
BUSY = 0x0007


def status(value: int):
    return [("w", A, b"\x00\x02"), ("r", A, value.to_bytes(2, "big"))]


def write(register: int, *words: int):
    return [("w", A, register.to_bytes(2, "big") + b"".join(w.to_bytes(2, "big") for w in words))]


def read_data(*words: int):
    return [("w", A, b"\x00\x08"), ("r", A, b"".join(w.to_bytes(2, "big") for w in words))]


class FakeClock:
    def __init__(self):
        self.t = 0.0
        self.sleeps = 0

    def now(self):
        return self.t

    def sleep(self, dt):
        self.t += dt
        self.sleeps += 1


def lepton(bus, clock=None):
    clock = clock or FakeClock()
    d = Lepton35(RegisterIO(bus, A, reg_bytes=2, bus_name="port 2"))
    d.cci = cci.CCI(
        d.io, timeout_s=0.003, poll_interval_s=0.001, sleep=clock.sleep, clock=clock.now
    )
    return d


def ping_script():
    return [status(READY), write(0x0006, 0), write(0x0004, 0x0202), status(READY)]


def set_script(command: int, *words: int):
    return [
        status(READY),
        write(0x0008, *words),
        write(0x0006, len(words)),
        write(0x0004, command | 1),
        status(READY),
    ]


# -- the protocol --------------------------------------------------------------------------


def test_ping_is_run_0x0202_with_busy_polling():
    bus = ScriptedBus(
        [
            status(BUSY),  # still busy from before: poll again
            status(READY),
            write(0x0006, 0),  # data length 0
            write(0x0004, 0x0202),  # SYS ping, RUN
            status(BUSY),
            status(BUSY),
            status(READY),
        ]
    )
    clock = FakeClock()
    lepton(bus, clock).ping()
    bus.done()
    assert clock.sleeps == 3


def test_get_fpa_temperature_writes_length_then_command_and_reads_data0():
    bus = ScriptedBus(
        [
            status(READY),
            write(0x0006, 1),
            write(0x0004, 0x0214),  # SYS FPA temperature, GET
            status(BUSY),
            status(READY),
            read_data(30_137),  # 301.37 K in 0.01 K
        ]
    )
    assert lepton(bus).fpa_temperature_k() == pytest.approx(301.37)
    bus.done()


def test_multi_word_attributes_are_least_significant_word_first():
    bus = ScriptedBus(
        [
            status(READY),
            write(0x0006, 2),
            write(0x0004, 0x020C),
            status(READY),
            read_data(0x1234, 1),
        ]
    )
    assert lepton(bus).cci.get_value(cci.COMMANDS["SYS_UPTIME"]) == 0x0001_1234
    bus.done()
    assert cci.words_of(0x0001_1234, 2) == [0x1234, 0x0001]


def test_set_vsync_is_oem_gpio_mode_5_with_the_protection_bit():
    bus = ScriptedBus(set_script(0x4854, 5, 0))
    d = lepton(bus)
    d.set_vsync(True)
    d.set_vsync(True)  # the same value again: nothing sent
    bus.done()
    bus.script = set_script(0x4854, 0, 0)
    d.set_vsync(False)
    bus.done()


def test_gpio_mode_get():
    bus = ScriptedBus(
        [status(READY), write(0x0006, 2), write(0x0004, 0x4854), status(READY), read_data(5, 0)]
    )
    assert lepton(bus).gpio_mode() == 5
    bus.done()


def test_run_ffc_is_0x0242():
    bus = ScriptedBus(
        [
            status(READY),
            write(0x0006, 0),
            write(0x0004, 0x0242),
            *[status(BUSY)] * 2,
            status(READY),
        ]
    )
    lepton(bus).run_ffc()
    bus.done()


@pytest.mark.parametrize(
    ("method", "command", "value"),
    [
        ("set_radiometry", 0x4E10, 1),
        ("set_tlinear", 0x4EC0, 1),
    ],
)
def test_radiometry_and_tlinear_enable(method, command, value):
    bus = ScriptedBus(set_script(command, value, 0))
    getattr(lepton(bus), method)(True)
    bus.done()


def test_tlinear_resolution_set_and_get():
    bus = ScriptedBus(
        [
            *set_script(0x4EC4, 0, 0),  # 0 = 0.1 K
            status(READY),
            write(0x0006, 2),
            write(0x0004, 0x4EC4),
            status(READY),
            read_data(1, 0),  # 1 = 0.01 K
        ]
    )
    d = lepton(bus)
    d.set_tlinear_resolution_k(0.1)
    assert d.tlinear_resolution_k() == 0.01
    bus.done()


def test_error_code_is_a_typed_error_naming_the_command_and_the_code():
    bus = ScriptedBus(
        [status(READY), write(0x0006, 1), write(0x0004, 0x0214), status(0xF906)]  # error -7
    )
    with pytest.raises(LeptonError) as info:
        lepton(bus).fpa_temperature_k()
    err = info.value
    assert err.code == -7 and err.command == 0x0214
    assert "SYS_FPA_TEMPERATURE GET (0x0214)" in str(err) and "error -7" in str(err)
    assert (err.bus, err.address) == ("port 2", 0x2A)
    assert isinstance(err, I2CError)
    bus.done()


def test_set_error_leaves_no_shadow_so_the_next_set_is_sent():
    bus = ScriptedBus(
        [
            status(READY),
            write(0x0008, 5, 0),
            write(0x0006, 2),
            write(0x0004, 0x4855),
            status(0xFD06),  # -3, range error
            *set_script(0x4854, 5, 0),
        ]
    )
    d = lepton(bus)
    with pytest.raises(LeptonError, match="range error"):
        d.set_vsync(True)
    d.set_vsync(True)
    bus.done()


def test_busy_past_the_timeout_is_a_timeout_error():
    bus = ScriptedBus([status(BUSY)] * 4)  # polls at 0, 1, 2, 3 ms; 2.5 ms is the limit
    with pytest.raises(cci.CCITimeoutError) as info:
        lepton(bus).ping()
    assert isinstance(info.value, TimeoutError) and isinstance(info.value, LeptonError)
    assert "stayed busy" in str(info.value) and "SYS_PING RUN" in str(info.value)
    bus.done()


# -- detection and the parameter model -----------------------------------------------------


def test_probe_checks_status_boot_bits_then_pings():
    bus = ScriptedBus([status(READY), status(READY), *ping_script()])
    assert isinstance(Lepton35.probe(bus, bus_name="port 2"), Lepton35)
    bus.done()


def test_probe_waits_for_boot_to_complete():
    bus = ScriptedBus([status(0x0001), status(0x0001), status(READY), *ping_script()])
    assert isinstance(Lepton35.probe(bus, bus_name="port 2"), Lepton35)
    bus.done()


def test_probe_rejects_a_device_with_reserved_status_bits():
    bus = ScriptedBus([status(0xFFFF)])
    assert Lepton35.probe(bus, bus_name="port 2") is None
    bus.done()


def test_detect_tries_both_aptina_sensors_first():
    bus = ScriptedBus([*[errno.EREMOTEIO] * 4, status(READY), status(READY), *ping_script()])
    assert isinstance(detect(bus, bus_name="port 2"), Lepton35)
    bus.done()


def test_init_is_elphels_list_vsync_telemetry_off_footer():
    bus = ScriptedBus(
        [
            status(READY),  # booted
            *set_script(0x4854, 5, 0),  # OEM GPIO mode: VSYNC on GPIO3
            *set_script(0x0218, 0, 0),  # SYS telemetry enable: off
            *set_script(0x021C, 1, 0),  # SYS telemetry location: footer
        ]
    )
    lepton(bus).init()
    bus.done()


def test_woi_height_122_turns_telemetry_on_through_program():
    bus = ScriptedBus(set_script(0x0218, 1, 0))
    d = lepton(bus)
    d.settings["SYS_TELEMETRY_ENABLE"] = 0
    s = d.normalize({**d.defaults(), "WOI_HEIGHT": 122}, frozenset({"WOI_HEIGHT"}))
    assert d.program(WINDOW, s) == ["SYS_TELEMETRY_ENABLE"]
    assert d.program(WINDOW, s) == []
    assert d.program(EXPOSURE, s) == []
    # No frame-synchronised registers: the Lepton is a command sensor, not a register file.
    assert isinstance(d, CommandSensor) and not isinstance(d, RegisterFileSensor)
    assert not hasattr(d, "registers") and not hasattr(d, "table")
    # Its raw register view is the CCI interface itself, read as it is (no shadow).
    raw = register_file(d)
    assert raw.table is cci.REGISTERS
    assert [r.name for r in raw.table][:3] == ["power", "status", "command"]
    bus.done()


def test_parameter_model_is_fixed_160x120_free_running_8_7_fps():
    d = lepton(ScriptedBus([]))
    s = d.defaults()
    assert (s["WOI_WIDTH"], s["WOI_HEIGHT"], s["TRIG"], s["FP1000S"]) == (160, 120, 0, 8700)
    assert d.frame_period_s(s) == pytest.approx(1 / 8.7)
    assert all(d.latency(fn, s) == 1 for fn in d.ahead)


def test_command_words_carry_the_protection_bit_for_oem_and_rad():
    assert cci.command_id(cci.Module.OEM, 0x54, cci.CommandType.SET) == 0x4855
    assert cci.command_id(cci.Module.RAD, 0xC0, cci.CommandType.GET) == 0x4EC0
    assert cci.command_id(cci.Module.SYS, 0x40, cci.CommandType.RUN) == 0x0242
    assert cci.COMMANDS["SYS_PING"].id(cci.CommandType.RUN) == 0x0202
    with pytest.raises(ValueError, match="cannot SET"):
        cci.COMMANDS["SYS_FPA_TEMPERATURE"].id(cci.CommandType.SET)
    with pytest.raises(ValueError, match="multiple of 4"):
        cci.command_id(cci.Module.SYS, 0x15, cci.CommandType.GET)


def test_error_code_is_signed():
    assert cci.error_code(0xF906) == -7
    assert cci.error_code(0x0006) == 0
