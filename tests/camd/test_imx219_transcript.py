"""Transcript tests of the IMX219: the exact I2C bytes of its byte registers and driver."""

import errno

import pytest

from elphel_camd.i2c.byte_registers import ByteRegisterIO
from elphel_camd.sensors import IMX219, detect
from elphel_camd.sensors import imx219_registers as regs
from tests.camd.scripted_bus import ScriptedBus

A = 0x10


def read(address, data):
    """A combined read of ``data`` from a 16-bit register address."""
    return [("w", A, address.to_bytes(2, "big")), ("r", A, data)]


def write(address, data):
    return [("w", A, address.to_bytes(2, "big") + data)]


def test_a_16bit_register_is_two_bytes_high_first_and_an_8bit_one_is_one():
    bus = ScriptedBus(
        [
            read(0x0000, b"\x02\x19"),
            write(0x015A, b"\x02\x11"),
            write(0x0157, b"\x80"),
            read(0x0172, b"\x03"),
        ]
    )
    io = IMX219.open_io(bus, bus_name="port 0")
    assert io.read_word(0x0000) == 0x0219
    io.write(0x015A, 0x0211)
    io.write(0x0157, 0x80)
    assert io.read_word(0x0172) == 3
    bus.done()


def test_values_wider_than_the_register_are_refused_before_any_transfer():
    io = IMX219.open_io(ScriptedBus([]), bus_name="port 0")
    with pytest.raises(ValueError, match=r"register 0x157; allowed: 0..0xff"):
        io.write(0x0157, 0x100)
    with pytest.raises(ValueError, match="1 or 2 bytes"):
        ByteRegisterIO(ScriptedBus([]), A, sizes={0x10: 4})


def test_consecutive_registers_are_read_in_one_transfer():
    bus = ScriptedBus([read(0x0164, b"\x00\x10\x01\x0f")])
    io = IMX219.open_io(bus, bus_name="port 0")
    assert io.read(0x0164, 2) == [0x0010, 0x010F]
    bus.done()


def test_detect_finds_the_imx219_by_its_chip_id_after_the_other_models():
    # MT9P006 and Lepton at other addresses NAK; the MT9F002 probe at 0x10 reads 0x3000
    # (one 16-bit word) and finds another id; then the IMX219 reads 0x0000.
    bus = ScriptedBus(
        [
            *[errno.EREMOTEIO] * 2,
            read(0x3000, b"\x00\x00"),
            *[errno.EREMOTEIO] * 2,
            read(0x0000, b"\x02\x19"),
        ]
    )
    assert isinstance(detect(bus, bus_name="port 0"), IMX219)
    bus.done()


def test_probe_rejects_another_chip_id():
    bus = ScriptedBus([read(0x0000, b"\x02\x20")])
    assert IMX219.probe(bus, bus_name="port 0") is None
    bus.done()


def _shadow_reads():
    """init reads every register once, in table order (reset values answered)."""
    script = []
    for r in regs.TABLE:
        n = regs.register_bytes(r)
        script.append(read(r.address, r.reset.to_bytes(n, "big")))
    return script


def test_init_reads_the_shadows_then_only_starts_streaming():
    # Every init write but the mode select already matches the reset values.
    bus = ScriptedBus([*_shadow_reads(), write(0x0100, b"\x01")])
    driver = IMX219(IMX219.open_io(bus, bus_name="port 0"))
    driver.init()
    bus.done()


def test_gains_window_exposure_and_frame_length_on_the_wire():
    bus = ScriptedBus([*_shadow_reads(), write(0x0100, b"\x01")])
    driver = IMX219(IMX219.open_io(bus, bus_name="port 0"))
    driver.init()
    state = driver.normalize(
        {**driver.defaults(), "GAING": 0x30000, "VEXPOS": 1000, "FLIPH": 1},
        frozenset({"GAING", "VEXPOS", "FLIPH"}),
    )
    # gain 3.0: analogue code 170 (2.977x), digital 0x0102 (1.008x)
    bus.script = [write(0x0157, b"\xaa"), write(0x0158, b"\x01\x02")]
    assert driver.program("gains", state) == ["analogue_gain", "digital_gain"]
    bus.done()
    # 1000 lines: the frame is 2464 + 32 lines, longer than the exposure plus 4
    bus.script = [write(0x0160, (2464 + 32).to_bytes(2, "big"))]
    assert driver.program("limitfps", state) == ["frame_length_lines"]
    bus.script = [write(0x015A, b"\x03\xe8")]
    assert driver.program("exposure", state) == ["coarse_integration_time"]
    bus.script = [write(0x0172, b"\x01")]  # the whole window is the reset crop already
    assert driver.program("window", state) == ["orientation"]
    bus.done()
