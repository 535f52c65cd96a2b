"""Register tables as data.

A sensor is declared once as a `RegisterTable`: every register with its address, width,
access, reset value, limits, unit and meaning. The drivers read and write through it, the
parameter validation takes limits from it, and the simulator builds its chip models from
the same table, so the two cannot drift apart. A table checks itself when it is built.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from enum import StrEnum


class Access(StrEnum):
    RO = "ro"
    RW = "rw"
    WO = "wo"


@dataclass(frozen=True)
class Register:
    """One 16-bit register (or a word of a multi-word register) of a sensor.

    Parameters
    ----------
    name
        Identifier used by drivers, the REST raw-register view and the simulator.
    address
        Register address (8-bit for MT9P006, 16-bit for MT9F002 and the Lepton CCI).
    reset
        Value after power-up or soft reset.
    access
        Read-only, read-write or write-only.
    minimum, maximum
        Allowed values (inclusive); defaults cover the whole width.
    width
        Number of significant bits (<= 16).
    unit
        Unit of the value ("rows", "columns", "code", ...).
    doc
        What the register does.
    """

    name: str
    address: int
    reset: int
    access: Access = Access.RW
    minimum: int = 0
    maximum: int | None = None
    width: int = 16
    unit: str = ""
    doc: str = ""

    @property
    def limit(self) -> int:
        """Largest allowed value."""
        return self.maximum if self.maximum is not None else (1 << self.width) - 1

    def check(self, value: int) -> None:
        """Raise ValueError naming the register, the value and the allowed range."""
        if not self.minimum <= value <= self.limit:
            raise ValueError(
                f"{self.name} (0x{self.address:x}) = {value}; allowed {self.minimum}..{self.limit}"
            )


class RegisterTable:
    """An ordered, self-checked set of registers of one sensor model.

    Parameters
    ----------
    model
        Sensor model name, e.g. ``"MT9P006"``.
    registers
        The registers; names and addresses must be unique.
    address_bytes
        Width of a register address on the wire (1 or 2).
    """

    def __init__(self, model: str, registers: list[Register], *, address_bytes: int) -> None:
        self.model = model
        self.address_bytes = address_bytes
        self._by_name: dict[str, Register] = {}
        self._by_address: dict[int, Register] = {}
        top = 1 << (8 * address_bytes)
        for r in registers:
            if r.name in self._by_name:
                raise ValueError(f"{model}: register name {r.name!r} declared twice")
            if r.address in self._by_address:
                other = self._by_address[r.address].name
                raise ValueError(f"{model}: {r.name} and {other} share address 0x{r.address:x}")
            if not 0 <= r.address < top:
                raise ValueError(f"{model}: {r.name} address 0x{r.address:x} exceeds the bus width")
            if not 1 <= r.width <= 16:
                raise ValueError(f"{model}: {r.name} width {r.width} is not 1..16")
            if r.limit >= 1 << r.width or r.minimum > r.limit:
                raise ValueError(f"{model}: {r.name} limits {r.minimum}..{r.limit} do not fit")
            if r.access is not Access.WO and not r.minimum <= r.reset <= r.limit:
                raise ValueError(f"{model}: {r.name} reset 0x{r.reset:x} is outside its limits")
            self._by_name[r.name] = r
            self._by_address[r.address] = r

    def __getitem__(self, name: str) -> Register:
        try:
            return self._by_name[name]
        except KeyError:
            raise KeyError(f"{self.model} has no register {name!r}") from None

    def __iter__(self) -> Iterator[Register]:
        return iter(self._by_name.values())

    def __len__(self) -> int:
        return len(self._by_name)

    def __contains__(self, name: object) -> bool:
        return name in self._by_name

    def at(self, address: int) -> Register | None:
        """The register at an address, or None if the table does not declare one."""
        return self._by_address.get(address)
