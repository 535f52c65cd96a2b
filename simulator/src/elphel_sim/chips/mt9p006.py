"""Simulated MT9P006: its register file from the daemon's table, plus the chip's aliases."""

from __future__ import annotations

from elphel_camd.sensors import mt9p006 as spec
from elphel_sim.chips.registers import SimRegisterChip

_COLOUR_GAINS = ("green1_gain", "blue_gain", "red_gain", "green2_gain")


class SimMT9P006(SimRegisterChip):
    """MT9P006 at I2C address 0x48 with 8-bit register addresses."""

    address = spec.I2C_ADDRESS

    def __init__(self) -> None:
        super().__init__(spec.TABLE, step=1)

    def on_register_write(self, address: int, value: int) -> None:
        table = self.table
        if address == table["global_gain"].address:
            # The global gain register writes all four colour gains.
            for name in _COLOUR_GAINS:
                self.values[table[name].address] = value
        elif address == table["reset"].address and value & 1:
            self.reset()
            return
        elif address == table["restart"].address:
            value &= ~1  # restart is self-clearing
        super().on_register_write(address, value)
