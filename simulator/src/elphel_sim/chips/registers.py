"""A chip whose I2C interface is a file of 16-bit registers, built from a RegisterTable.

Covers the Aptina sensors' register protocol: a write carries the register address
(1 or 2 bytes) and then any number of big-endian 16-bit words to consecutive registers; a
read returns words from the last addressed register on, auto-incrementing. Writes to
read-only registers are ignored, as the chips do. Behaviour beyond the register file
(latencies, gain aliasing, triggers) belongs to subclasses via ``on_register_write``.
"""

from __future__ import annotations

from elphel_camd.sensors.registers import Access, RegisterTable


class SimRegisterChip:
    """Register file of one chip.

    Parameters
    ----------
    table
        The same table the daemon's driver uses.
    step
        Address increment between consecutive 16-bit registers (1 for 8-bit addresses,
        2 for byte-addressed 16-bit maps).
    """

    def __init__(self, table: RegisterTable, *, step: int = 1) -> None:
        self.table = table
        self.step = step
        self.values: dict[int, int] = {
            r.address: r.reset for r in table if r.access is not Access.WO
        }
        self._pointer = 0
        self.write_log: list[tuple[int, int]] = []

    def reset(self) -> None:
        self.values = {r.address: r.reset for r in self.table if r.access is not Access.WO}

    def peek(self, name: str) -> int:
        """The value of a named register, without a bus transfer."""
        return self.values[self.table[name].address]

    def on_register_write(self, address: int, value: int) -> None:
        """Store a written word; subclasses add the chip's side effects."""
        register = self.table.at(address)
        if register is not None and register.access is Access.RO:
            return
        self.values[address] = value

    def on_write(self, data: bytes) -> None:
        n = self.table.address_bytes
        if len(data) < n:
            return
        self._pointer = int.from_bytes(data[:n], "big")
        payload = data[n:]
        for i in range(0, len(payload) - 1, 2):
            value = int.from_bytes(payload[i : i + 2], "big")
            self.write_log.append((self._pointer, value))
            self.on_register_write(self._pointer, value)
            self._pointer += self.step

    def on_read(self, length: int) -> bytes:
        out = bytearray()
        while len(out) < length:
            out += self.values.get(self._pointer, 0).to_bytes(2, "big")
            self._pointer += self.step
        return bytes(out[:length])

    def on_stop(self) -> None:
        """Nothing latches at STOP for a plain register file."""
