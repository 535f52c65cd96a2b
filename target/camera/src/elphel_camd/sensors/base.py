"""What every sensor driver shares: probing by chip id and table-checked register access."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, ClassVar

from elphel_camd.errors import I2CError
from elphel_camd.i2c.bus import I2CBus
from elphel_camd.i2c.regio import RegisterIO
from elphel_camd.sensors.registers import Access, RegisterTable


class SensorDriver(ABC):
    """Base of the drivers. A driver receives a ready `RegisterIO`; it never opens a bus.

    Subclasses set the class attributes that identify the model.
    """

    model: ClassVar[str]
    table: ClassVar[RegisterTable]
    i2c_address: ClassVar[int]
    chip_id_register: ClassVar[str]
    chip_id: ClassVar[int]
    chip_id_mask: ClassVar[int] = 0xFFFF
    sensor_code: ClassVar[int]
    bayer: ClassVar[str | None]
    bits: ClassVar[int]

    def __init__(self, io: RegisterIO) -> None:
        self.io = io

    @classmethod
    def probe(cls, bus: I2CBus, *, bus_name: str) -> SensorDriver | None:
        """Return a driver if this model answers on the bus with its chip id, else None."""
        io = RegisterIO(
            bus, cls.i2c_address, reg_bytes=cls.table.address_bytes, bus_name=bus_name, retries=1
        )
        try:
            value = io.read_word(cls.table[cls.chip_id_register].address)
        except I2CError:
            return None
        if value & cls.chip_id_mask != cls.chip_id & cls.chip_id_mask:
            return None
        return cls(io)

    def read(self, name: str) -> int:
        """Read a register by its table name."""
        register = self.table[name]
        if register.access is Access.WO:
            raise ValueError(f"{self.model} register {name} is write-only")
        return self.io.read_word(register.address)

    def write(self, name: str, value: int) -> None:
        """Write a register by its table name, checked against the table's limits."""
        register = self.table[name]
        if register.access is Access.RO:
            raise ValueError(f"{self.model} register {name} is read-only")
        register.check(value)
        self.io.write(register.address, value)

    def identity(self) -> dict[str, Any]:
        """Model, chip id read now, I2C address and what the model delivers."""
        return {
            "model": self.model,
            "chip_id": self.read(self.chip_id_register),
            "i2c_address": self.i2c_address,
            "sensor_code": self.sensor_code,
            "bayer": self.bayer,
            "bits": self.bits,
        }

    @abstractmethod
    def read_params(self) -> dict[str, int]:
        """Frame parameters (Elphel names and units) as the sensor's registers hold them now."""
