"""Sensors whose I2C interface is a file of registers: table, shadows, bit fields.

Probing by chip id, shadowed register access by name, and field access. A register-file
driver writes a register only when the value differs from its shadow, and keeps the
shadow equal to the chip: after a failed transfer it re-reads the register.
"""

from __future__ import annotations

import logging
from abc import abstractmethod
from collections.abc import Mapping
from typing import ClassVar, Protocol, cast

from elphel_camd.errors import I2CError, UnsupportedError
from elphel_camd.i2c.bus import I2CBus
from elphel_camd.i2c.regio import RegisterIO
from elphel_camd.sensors.base import SensorDriver
from elphel_camd.sensors.registers import Access, RegisterTable

log = logging.getLogger(__name__)


class RegisterFileSensor(SensorDriver):
    """A driver that reaches its chip through a `RegisterTable`.

    Subclasses set the table and the chip id and say, per program function, which
    register values a state needs (`registers`).

    Parameters
    ----------
    io
        Register access at the model's I2C address and register-address width.
    """

    table: ClassVar[RegisterTable]
    chip_id_register: ClassVar[str]
    chip_id: ClassVar[int]
    chip_id_mask: ClassVar[int] = 0xFFFF

    def __init__(self, io: RegisterIO) -> None:
        self.io = io
        self.shadow: dict[str, int] = {}

    @classmethod
    def probe(cls, bus: I2CBus, *, bus_name: str) -> RegisterFileSensor | None:
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

    def read_chip_id(self) -> int:
        return self.read(self.chip_id_register)

    # -- registers -------------------------------------------------------------------------

    def read(self, name: str) -> int:
        """Read a register by its table name (and refresh its shadow)."""
        register = self.table[name]
        if register.access is Access.WO:
            raise ValueError(f"{self.model} register {name} is write-only")
        value = self.io.read_word(register.address)
        self.shadow[name] = value
        return value

    def write(self, name: str, value: int) -> None:
        """Write a register by its table name, checked against the table's limits.

        On a failed transfer the register is read back, so the shadow never disagrees with
        the chip; the error is raised again.
        """
        register = self.table[name]
        if register.access is Access.RO:
            raise ValueError(f"{self.model} register {name} is read-only")
        register.check(value)
        try:
            self.io.write(register.address, value)
        except I2CError:
            self.shadow.pop(name, None)
            try:
                self.read(name)
            except I2CError:
                log.warning("%s: %s unreadable after a failed write", self.io.bus_name, name)
            raise
        self.shadow[name] = value

    def write_if_changed(self, name: str, value: int) -> bool:
        """Write only when the value differs from the shadow (Elphel's discipline)."""
        if self.shadow.get(name) == value:
            return False
        self.write(name, value)
        return True

    def sync_shadow(self) -> None:
        """Read every readable register into the shadow."""
        for register in self.table:
            if register.access is not Access.WO:
                self.read(register.name)

    # -- fields ----------------------------------------------------------------------------

    def fields_of(self, register: str, value: int) -> dict[str, int]:
        """A value of a register decoded into its declared fields (empty if none)."""
        return self.table.fields_of(register, value)

    def field(self, name: str) -> int:
        """A field's value in the shadow (reset value if never read), by ``"register.field"``."""
        bound = self.table.field(name)
        return bound.get(self.shadow.get(bound.register.name, bound.register.reset))

    # -- parameter model -------------------------------------------------------------------

    def init(self) -> None:
        """Bring the chip to a known state: read the shadows (models add their init writes)."""
        self.sync_shadow()

    def program(self, function: str, state: Mapping[str, int]) -> list[str]:
        """Write the registers of one function for a state; return the names written."""
        written = []
        for name, value in self.registers(function, state).items():
            if self.write_if_changed(name, value):
                written.append(name)
        return written

    @abstractmethod
    def registers(self, function: str, state: Mapping[str, int]) -> dict[str, int]:
        """Register values a program function writes for a state."""


class RawRegisters(Protocol):
    """Raw, table-checked access to a chip's registers (the REST admin view)."""

    @property
    def table(self) -> RegisterTable: ...

    def read(self, name: str) -> int: ...

    def write(self, name: str, value: int) -> None: ...


class InterfaceRegisters:
    """The registers of a command-protocol chip's interface, e.g. the Lepton's CCI.

    They are real I2C registers (power, status, command, data words), but the sensor's
    settings are commands sent through them, so they carry no shadow and no fields the
    parameter model uses: this is the admin's raw view only.
    """

    def __init__(self, io: RegisterIO, table: RegisterTable) -> None:
        self.io = io
        self.table = table

    def read(self, name: str) -> int:
        register = self.table[name]
        if register.access is Access.WO:
            raise ValueError(f"register {name} is write-only")
        return self.io.read_word(register.address)

    def write(self, name: str, value: int) -> None:
        register = self.table[name]
        if register.access is Access.RO:
            raise ValueError(f"register {name} is read-only")
        register.check(value)
        self.io.write(register.address, value)


def register_file(driver: SensorDriver) -> RawRegisters:
    """A driver's registers for raw access: its register file, or its command interface's.

    UnsupportedError for a driver with neither.
    """
    if isinstance(driver, RegisterFileSensor):
        return driver
    interface = getattr(driver, "interface_registers", None)
    if interface is None:
        raise UnsupportedError(
            f"{driver.model} has no registers to read or write raw "
            "(allowed: a register-file sensor such as MT9P006, or a CCI device)"
        )
    return cast(RawRegisters, interface)
