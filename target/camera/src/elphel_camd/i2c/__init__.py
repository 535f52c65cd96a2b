"""I2C seam: the bus protocol, register access and the smbus2 transport."""

from elphel_camd.i2c.bus import I2CBus, open_bus
from elphel_camd.i2c.regio import RegisterIO

__all__ = ["I2CBus", "RegisterIO", "open_bus"]
