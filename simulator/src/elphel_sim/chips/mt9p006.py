"""Simulated MT9P006: register file, aliases, and when a write reaches the image.

The register file comes from the daemon's table.

Timing (datasheet facts, reference sections 1.2 and 1.4): in free-run, a write to the
shutter width, the window, blanking or read modes made during frame F shapes the image of
frame F + 2 (window changes cost a bubble frame); colour gains reach frame F + 1. In
snapshot mode every frame-synchronised register reaches the next triggered frame.
Registers outside these groups (reset, restart, test pattern, ...) act at once.
"""

from __future__ import annotations

from elphel_camd.sensors import mt9p006 as spec
from elphel_camd.sensors.registers import Access
from elphel_sim.chips.registers import SimRegisterChip

_COLOUR_GAINS = ("green1_gain", "blue_gain", "red_gain", "green2_gain")
_TWO_FRAMES = (
    "shutter_width_upper",
    "shutter_width_lower",
    "row_start",
    "column_start",
    "row_size",
    "column_size",
    "horizontal_blank",
    "vertical_blank",
    "read_mode_1",
    "read_mode_2",
    "row_address_mode",
    "column_address_mode",
)
SNAPSHOT_BIT = 0x0100  # read_mode_1 bit 8


class SimMT9P006(SimRegisterChip):
    """MT9P006 at I2C address 0x48 with 8-bit register addresses."""

    address = spec.I2C_ADDRESS

    def __init__(self) -> None:
        super().__init__(spec.TABLE, step=1)
        self._latency = {spec.TABLE[name].address: 2 for name in _TWO_FRAMES}
        self._latency.update({spec.TABLE[name].address: 1 for name in _COLOUR_GAINS})
        self.effective: dict[int, int] = dict(self.values)
        self.frame = 0
        self._queue: list[tuple[int, int, int]] = []

    def reset(self) -> None:
        super().reset()
        self.effective = dict(self.values)
        self._queue = []

    def latency(self, address: int) -> int:
        frames = self._latency.get(address, 0)
        snapshot = self.effective[spec.TABLE["read_mode_1"].address] & SNAPSHOT_BIT
        return min(frames, 1) if snapshot else frames

    def _store(self, address: int, value: int) -> None:
        self.values[address] = value
        frames = self.latency(address)
        if frames == 0:
            self.effective[address] = value
        else:
            self._queue.append((self.frame + frames, address, value))

    def on_register_write(self, address: int, value: int) -> None:
        table = self.table
        if address == table["global_gain"].address:
            # The global gain register writes all four colour gains.
            for name in _COLOUR_GAINS:
                self._store(table[name].address, value)
            self.values[address] = value
        elif address == table["reset"].address and value & 1:
            self.reset()
        elif address == table["restart"].address:
            self.values[address] = value & ~1  # restart is self-clearing
        elif (register := table.at(address)) is not None and register.access is Access.RO:
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
