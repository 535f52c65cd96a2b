"""Register access on adapters that offer only SMBus: word-data transfers in place of I2C.

Some adapters (i2c-stub, many PC SMBus controllers, some SoC controllers) cannot run a
plain I2C combined transfer; they offer SMBus commands only. A sensor with 8-bit register
addresses and 16-bit registers (the MT9P006) is still reachable through SMBus word data:
one register per word command. SMBus sends a word low byte first, the sensor high byte
first, so each word is byte-swapped on the way in and out.

`SMBusWordBus` answers the two transfers `elphel_camd.i2c.regio.RegisterIO` makes (a
register write, and a register-address write followed by a read) with word commands.
"""

from __future__ import annotations

import ctypes
import errno
from typing import Protocol

from smbus2 import i2c_msg

I2C_M_RD = 0x0001


class SMBusWords(Protocol):
    """What this bus needs from smbus2's ``SMBus``: word-data commands."""

    def read_word_data(self, i2c_addr: int, register: int) -> int: ...

    def write_word_data(self, i2c_addr: int, register: int, value: int) -> None: ...


def _swap(word: int) -> int:
    return ((word & 0xFF) << 8) | (word >> 8)


class SMBusWordBus:
    """An I2C bus whose adapter offers only SMBus, for 8-bit-address word registers.

    Parameters
    ----------
    smbus
        The open adapter (smbus2 ``SMBus``).
    name
        The adapter's name in messages.
    """

    mode = "smbus-word"

    def __init__(self, smbus: SMBusWords, *, name: str) -> None:
        self.smbus = smbus
        self.name = name

    def i2c_rdwr(self, *msgs: i2c_msg) -> None:
        """Run a register write, or a register read, as SMBus word commands."""
        if len(msgs) == 1 and not msgs[0].flags & I2C_M_RD:
            self._write(msgs[0])
        elif len(msgs) == 2 and not msgs[0].flags & I2C_M_RD and msgs[1].flags & I2C_M_RD:
            self._read(msgs[0], msgs[1])
        else:
            raise OSError(
                errno.EOPNOTSUPP,
                f"{self.name} offers only SMBus: a transfer of {len(msgs)} messages has no "
                "SMBus word equivalent",
            )

    def _register(self, msg: i2c_msg, payload: bytes) -> int:
        if len(payload) < 1 or (len(payload) - 1) % 2:
            raise OSError(
                errno.EOPNOTSUPP,
                f"{self.name} offers only SMBus word transfers: device 0x{msg.addr:02x} needs "
                "8-bit register addresses and 16-bit words (a 16-bit register address needs "
                "an adapter with plain I2C)",
            )
        return payload[0]

    def _write(self, msg: i2c_msg) -> None:
        payload = bytes(msg)
        register = self._register(msg, payload)
        for k in range(0, len(payload) - 1, 2):
            word = int.from_bytes(payload[1 + k : 3 + k], "big")
            self.smbus.write_word_data(msg.addr, register + k // 2, _swap(word))

    def _read(self, address_msg: i2c_msg, read_msg: i2c_msg) -> None:
        payload = bytes(address_msg)
        if len(payload) != 1 or read_msg.len % 2:
            self._register(address_msg, b"")  # raises: not an 8-bit address and whole words
        register = payload[0]
        data = bytearray()
        for k in range(read_msg.len // 2):
            word = _swap(self.smbus.read_word_data(read_msg.addr, register + k))
            data += word.to_bytes(2, "big")
        ctypes.memmove(read_msg.buf, bytes(data), len(data))
