"""What every sensor driver shares, and its contract with the frame sequencer.

Probing by chip id, shadowed register access, and the parameter model.

A driver turns a port's full parameter state into register values, one program function
at a time (`registers`), and says how many frames ahead each function must be issued
(`latency`). It writes a register only when the value differs from its shadow, and keeps
the shadow equal to the chip: after a failed transfer it re-reads the register.
"""

from __future__ import annotations

import logging
from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import Any, ClassVar

from elphel_camd.errors import I2CError, UnsupportedError
from elphel_camd.i2c.bus import I2CBus
from elphel_camd.i2c.regio import RegisterIO
from elphel_camd.params import TRIG_SNAPSHOT
from elphel_camd.sensors.registers import Access, RegisterTable

log = logging.getLogger(__name__)

State = dict[str, int]


class SensorDriver(ABC):
    """Base of the drivers. A driver receives a ready `RegisterIO`; it never opens a bus.

    Subclasses set the class attributes that identify the model and implement the
    parameter model (`defaults`, `normalize`, `registers`).
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
    # Frames before the target frame at which each program function's writes are issued:
    # (free-running, snapshot). Functions not listed write nothing on this sensor.
    ahead: ClassVar[Mapping[str, tuple[int, int]]]
    # Parameters this sensor accepts writes to; others are rejected with UnsupportedError.
    writable: ClassVar[frozenset[str]]

    def __init__(self, io: RegisterIO) -> None:
        self.io = io
        self.shadow: dict[str, int] = {}

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

    # -- parameter model -------------------------------------------------------------------

    def latency(self, function: str, state: Mapping[str, int]) -> int:
        """Frames ahead a function's writes must be issued in this state's trigger mode."""
        free_run, snapshot = self.ahead[function]
        return snapshot if state.get("TRIG", 0) & TRIG_SNAPSHOT else free_run

    def check_writable(self, names: Mapping[str, int]) -> None:
        for name in names:
            if name not in self.writable:
                raise UnsupportedError(f"{self.model} does not support setting {name}")

    def init(self) -> None:
        """Bring the chip to a known state: read the shadows, then the model's init writes."""
        self.sync_shadow()

    def program(self, function: str, state: Mapping[str, int]) -> list[str]:
        """Write the registers of one function for a state; return the names written."""
        written = []
        for name, value in self.registers(function, state).items():
            if self.write_if_changed(name, value):
                written.append(name)
        return written

    def actual_gains(self, state: Mapping[str, int]) -> dict[str, int]:
        """Gains the register codes really give (16.16), where they differ from the request."""
        return {}

    @abstractmethod
    def defaults(self) -> State:
        """The parameter state after init."""

    @abstractmethod
    def normalize(self, state: Mapping[str, int], changed: frozenset[str]) -> State:
        """Check a whole state (raise ParameterRangeError) and fill its derived values."""

    @abstractmethod
    def registers(self, function: str, state: Mapping[str, int]) -> dict[str, int]:
        """Register values a program function writes for a state."""

    @abstractmethod
    def frame_period_s(self, state: Mapping[str, int]) -> float:
        """Free-running frame period of the sensor in a state."""
