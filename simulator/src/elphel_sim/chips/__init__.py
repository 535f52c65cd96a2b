"""Simulated I2C devices built from the daemon's register tables, and the bus they sit on."""

from elphel_sim.chips.bus import SimI2CBus
from elphel_sim.chips.registers import SimRegisterChip

__all__ = ["SimI2CBus", "SimRegisterChip"]
