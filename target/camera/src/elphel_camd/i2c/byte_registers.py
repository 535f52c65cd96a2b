"""Register access to a chip whose registers are bytes at 16-bit addresses (the IMX219).

Such a chip (the SMIA / MIPI CCI register layout of Sony's sensors) keeps 8-bit
registers; a 16-bit value sits at two consecutive addresses, high byte first. A write is
one message, the register address then the value's bytes; a read is a combined transfer
(the address, a repeated start, then the value's bytes). How many bytes a register holds
comes from its table entry, so `read_word` and `write` keep the signature of
`elphel_camd.i2c.regio.RegisterIO` and the register-file drivers use either.
"""

from __future__ import annotations

from smbus2 import i2c_msg

from elphel_camd.i2c.bus import I2CBus
from elphel_camd.i2c.regio import RegisterIO


class ByteRegisterIO(RegisterIO):
    """Read and write the 8- and 16-bit registers of one device with 16-bit addresses.

    Parameters
    ----------
    bus
        An open bus (``smbus2.SMBus`` or a simulated one).
    address
        7-bit device address.
    sizes
        Bytes of each register by its address (1 or 2); an address not listed is 1 byte.
    bus_name
        Name used in error messages.
    retries
        How many times a NAKed transfer is tried again before it is reported.
    """

    def __init__(
        self,
        bus: I2CBus,
        address: int,
        *,
        sizes: dict[int, int],
        bus_name: str = "i2c",
        retries: int = 2,
    ) -> None:
        super().__init__(bus, address, reg_bytes=2, bus_name=bus_name, retries=retries)
        bad = {a: n for a, n in sizes.items() if n not in (1, 2)}
        if bad:
            raise ValueError(f"register sizes {bad}; allowed: 1 or 2 bytes")
        self.sizes = dict(sizes)

    def size(self, register: int) -> int:
        """Bytes of the register at an address."""
        return self.sizes.get(register, 1)

    def read_bytes(self, register: int, count: int) -> bytes:
        """Read ``count`` consecutive bytes from ``register`` on (one combined transfer)."""
        if count < 1:
            raise ValueError(f"count={count}; allowed: >= 1")
        write = i2c_msg.write(self.address, self._reg_address(register))
        read = i2c_msg.read(self.address, count)
        self._transfer(register, write, read)
        return bytes(read)

    def read_word(self, register: int) -> int:
        """Read one register (1 or 2 bytes, big-endian)."""
        return int.from_bytes(self.read_bytes(register, self.size(register)), "big")

    def read(self, register: int, count: int = 1) -> list[int]:
        """Read ``count`` registers of this register's size at consecutive addresses."""
        n = self.size(register)
        data = self.read_bytes(register, n * count)
        return [int.from_bytes(data[i : i + n], "big") for i in range(0, len(data), n)]

    def write(self, register: int, *words: int) -> None:
        """Write values of this register's size to consecutive addresses in one transfer."""
        if not words:
            raise ValueError("write needs at least one value")
        n = self.size(register)
        payload = bytearray(self._reg_address(register))
        for w in words:
            if not 0 <= w < 1 << (8 * n):
                top = (1 << (8 * n)) - 1
                raise ValueError(f"value={w!r} for register 0x{register:x}; allowed: 0..0x{top:x}")
            payload += w.to_bytes(n, "big")
        self._transfer(register, i2c_msg.write(self.address, bytes(payload)))
