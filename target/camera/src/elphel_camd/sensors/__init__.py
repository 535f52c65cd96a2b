"""Sensor register tables and drivers, and detection of which sensor sits on a port.

Every driver is a `SensorDriver` (the parameter model the sequencer and the service use)
and reaches its chip one of two ways: a `RegisterFileSensor` (MT9P006, MT9F002,
IMX219: a register table with shadows and bit fields) or a `CommandSensor` (the Lepton
3.5's CCI).
"""

from __future__ import annotations

from elphel_camd.i2c.bus import I2CBus
from elphel_camd.sensors.base import SensorDriver
from elphel_camd.sensors.command import CommandSensor
from elphel_camd.sensors.imx219 import IMX219
from elphel_camd.sensors.lepton35 import Lepton35
from elphel_camd.sensors.mt9f002 import MT9F002
from elphel_camd.sensors.mt9p006 import MT9P006
from elphel_camd.sensors.register_file import RegisterFileSensor, register_file

# Tried in this order on every port.
DRIVERS: tuple[type[SensorDriver], ...] = (MT9P006, MT9F002, Lepton35, IMX219)


def detect(bus: I2CBus, *, bus_name: str) -> SensorDriver | None:
    """The driver of the first known sensor that answers on the bus, or None."""
    for driver in DRIVERS:
        found = driver.probe(bus, bus_name=bus_name)
        if found is not None:
            return found
    return None


__all__ = [
    "DRIVERS",
    "IMX219",
    "MT9F002",
    "MT9P006",
    "CommandSensor",
    "Lepton35",
    "RegisterFileSensor",
    "SensorDriver",
    "detect",
    "register_file",
]
