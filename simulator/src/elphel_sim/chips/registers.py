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


class SimLatchedChip(SimRegisterChip):
    """A sensor's register file whose writes reach the image on a later frame.

    A write made during frame F is read back at once but shapes the image of frame
    ``F + latency(address)`` (0: at once). Subclasses say which registers are delayed by
    how much (`latency`), and name the colour-gain registers that ``global_gain`` writes.

    Parameters
    ----------
    table, step
        As for `SimRegisterChip`.
    colour_gains
        Registers the table's ``global_gain`` register writes together (none if empty).
    """

    def __init__(
        self, table: RegisterTable, *, step: int, colour_gains: tuple[str, ...] = ()
    ) -> None:
        super().__init__(table, step=step)
        self._colour_gains = tuple(table[name].address for name in colour_gains)
        self._global_gain = table["global_gain"].address if colour_gains else None
        self.effective: dict[int, int] = dict(self.values)
        self.frame = 0
        self._queue: list[tuple[int, int, int]] = []

    def reset(self) -> None:
        super().reset()
        self.effective = dict(self.values)
        self._queue = []

    def latency(self, address: int) -> int:
        """Frames until a write to this register reaches the image (0: at once)."""
        return 0

    def _store(self, address: int, value: int) -> None:
        self.values[address] = value
        frames = self.latency(address)
        if frames == 0:
            self.effective[address] = value
        else:
            self._queue.append((self.frame + frames, address, value))

    def on_register_write(self, address: int, value: int) -> None:
        register = self.table.at(address)
        if address == self._global_gain:
            for gain in self._colour_gains:
                self._store(gain, value)
            self.values[address] = value
        elif register is not None and register.access is Access.RO:
            return
        else:
            self._store(address, value)

    def latch(self, frame: int) -> None:
        """Frame ``frame`` starts: writes due by now reach the image."""
        self.frame = frame
        due = [q for q in self._queue if q[0] <= frame]
        self._queue = [q for q in self._queue if q[0] > frame]
        for _, address, value in due:
            self.effective[address] = value

    def image_register(self, name: str) -> int:
        """The value of a register as it shapes the current frame's image."""
        return self.effective[self.table[name].address]

    def image_field(self, name: str) -> int:
        """A field (``"register.field"``) as it shapes the current frame's image."""
        bound = self.table.field(name)
        return bound.get(self.effective[bound.register.address])

    def image_registers(self) -> dict[str, int]:
        """Every register as it shapes the current frame (recorded with the frame)."""
        return {r.name: self.effective[r.address] for r in self.table}
