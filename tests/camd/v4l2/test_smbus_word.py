"""Register access on an SMBus-only adapter: each transfer as the word commands it becomes."""

from __future__ import annotations

import pytest

from elphel_camd.i2c.regio import RegisterIO
from elphel_camd.i2c.smbus_word import SMBusWordBus


class ScriptedSMBus:
    """An SMBus adapter that expects exactly the word commands listed, in order."""

    def __init__(self, script: list[tuple[str, int, int, int]]) -> None:
        self.script = list(script)

    def _next(self, op: str, addr: int, register: int) -> int:
        assert self.script, f"unexpected {op} 0x{addr:02x} register 0x{register:02x}"
        want_op, want_addr, want_register, value = self.script.pop(0)
        assert (op, addr, register) == (want_op, want_addr, want_register)
        return value

    def read_word_data(self, i2c_addr: int, register: int) -> int:
        return self._next("read", i2c_addr, register)

    def write_word_data(self, i2c_addr: int, register: int, value: int) -> None:
        assert self._next("write", i2c_addr, register) == value


def test_a_register_read_is_one_word_command_per_register_byte_swapped() -> None:
    smbus = ScriptedSMBus([("read", 0x48, 0x00, 0x01_18), ("read", 0x48, 0x01, 0x14_00)])
    io = RegisterIO(SMBusWordBus(smbus, name="stub"), 0x48, reg_bytes=1)
    assert io.read(0x00, 2) == [0x1801, 0x0014]  # the sensor sends the high byte first
    assert not smbus.script


def test_a_register_write_is_one_word_command_per_word() -> None:
    smbus = ScriptedSMBus([("write", 0x48, 0x09, 0x34_12), ("write", 0x48, 0x0A, 0x00_01)])
    io = RegisterIO(SMBusWordBus(smbus, name="stub"), 0x48, reg_bytes=1)
    io.write(0x09, 0x1234, 0x0100)
    assert not smbus.script


def test_sixteen_bit_register_addresses_are_refused_naming_the_need_for_plain_i2c() -> None:
    io = RegisterIO(SMBusWordBus(ScriptedSMBus([]), name="stub"), 0x10, reg_bytes=2, retries=0)
    with pytest.raises(OSError, match="16-bit register address needs an adapter with plain I2C"):
        io.write(0x0100, 1)
