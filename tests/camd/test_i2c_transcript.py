"""Transcript tests: the exact I2C transfers of register access."""

import errno
import logging

import pytest
from smbus2 import i2c_msg

from elphel_camd.errors import I2CError
from elphel_camd.i2c import RegisterIO, open_bus
from elphel_camd.sensors import MT9P006, detect
from tests.camd.scripted_bus import ScriptedBus


def test_read_8bit_register_address_is_write_then_combined_read():
    bus = ScriptedBus([[("w", 0x48, b"\x00"), ("r", 0x48, b"\x18\x01")]])
    assert RegisterIO(bus, 0x48, reg_bytes=1).read_word(0x00) == 0x1801
    bus.done()


def test_read_16bit_register_address_and_several_words():
    bus = ScriptedBus([[("w", 0x10, b"\x30\x00"), ("r", 0x10, b"\x2e\x01\x00\x05")]])
    assert RegisterIO(bus, 0x10, reg_bytes=2).read(0x3000, 2) == [0x2E01, 0x0005]
    bus.done()


def test_write_is_one_message_big_endian():
    bus = ScriptedBus([[("w", 0x48, b"\x09\x07\x97")], [("w", 0x10, b"\x30\x56\x00\x10\x00\x20")]])
    RegisterIO(bus, 0x48, reg_bytes=1).write(0x09, 0x0797)
    RegisterIO(bus, 0x10, reg_bytes=2).write(0x3056, 0x10, 0x20)
    bus.done()


def test_nak_is_retried_then_succeeds_and_is_logged_once(caplog):
    bus = ScriptedBus([errno.EREMOTEIO, errno.EREMOTEIO, [("w", 0x48, b"\x20\x00\x40")]])
    io = RegisterIO(bus, 0x48, reg_bytes=1, bus_name="port 0", retries=2)
    with caplog.at_level(logging.DEBUG, "elphel_camd"):
        io.write(0x20, 0x0040)
    assert io.nak_count == 2
    bus.done()
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert warnings == [
        "port 0: device 0x48 register 0x20: went through at attempt 3 of 3, after: "
        "[Errno 121] scripted failure"
    ]


def test_persistent_nak_names_bus_address_and_register(caplog):
    bus = ScriptedBus([errno.EREMOTEIO] * 3)
    io = RegisterIO(bus, 0x48, reg_bytes=1, bus_name="port 2", retries=2)
    with pytest.raises(I2CError) as info, caplog.at_level(logging.DEBUG, "elphel_camd"):
        io.read_word(0x2B)
    # Raised, not logged: whoever catches it reports it (once).
    assert [r for r in caplog.records if r.levelno >= logging.WARNING] == []
    err = info.value
    assert (err.bus, err.address, err.register) == ("port 2", 0x48, 0x2B)
    assert "port 2" in str(err) and "0x48" in str(err) and "0x2b" in str(err)
    assert isinstance(err, OSError)
    bus.done()


def test_values_and_registers_out_of_range_are_rejected_before_any_transfer():
    io = RegisterIO(ScriptedBus([]), 0x48, reg_bytes=1)
    with pytest.raises(ValueError, match=r"0\.\.0xffff"):
        io.write(0x09, 0x10000)
    with pytest.raises(ValueError, match=r"0\.\.0xff"):
        io.read_word(0x100)
    with pytest.raises(ValueError, match="7-bit"):
        RegisterIO(ScriptedBus([]), 0x80, reg_bytes=1)


def test_detect_mt9p006_by_chip_version():
    bus = ScriptedBus([[("w", 0x48, b"\x00"), ("r", 0x48, b"\x18\x01")]])
    driver = detect(bus, bus_name="port 0")
    assert isinstance(driver, MT9P006)
    bus.done()


def test_detect_reports_nothing_when_no_device_answers(caplog):
    # Each known sensor is probed twice (one retry): MT9P006, MT9F002, Lepton 3.5, IMX219.
    bus = ScriptedBus([errno.EREMOTEIO] * 8)
    with caplog.at_level(logging.DEBUG, "elphel_camd"):
        assert detect(bus, bus_name="port 1") is None
    bus.done()
    # A sensor that is not there is what probing finds out, not a failure: debug lines only.
    assert [r.getMessage() for r in caplog.records if r.levelno > logging.DEBUG] == []
    assert len(caplog.records) == 8


def test_detect_rejects_other_chip_id():
    bus = ScriptedBus([[("w", 0x48, b"\x00"), ("r", 0x48, b"\x84\x11")], *[errno.EREMOTEIO] * 6])
    assert detect(bus, bus_name="port 0") is None
    bus.done()


def test_open_bus_rejects_non_i2c_urls():
    with pytest.raises(ValueError, match="/dev/i2c-N"):
        open_bus("/dev/ttyUSB0")
    with pytest.raises(ValueError, match="scheme"):
        open_bus("socket://localhost:23")


def test_scripted_bus_catches_wrong_bytes():
    bus = ScriptedBus([[("w", 0x48, b"\x09\x00\x01")]])
    with pytest.raises(AssertionError):
        bus.i2c_rdwr(i2c_msg.write(0x48, b"\x09\x00\x02"))
