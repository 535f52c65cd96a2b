"""Register tables as data: registers, their bit fields, and parameter -> field rules.

A sensor is declared once as a `RegisterTable`: every register with its address, width,
access, reset value, limits, unit, meaning and bit fields. The drivers read and write
through it, the parameter validation takes limits from it, and the simulator builds its
chip models from the same table, so the two cannot drift apart. A table checks itself
when it is built: names and addresses unique, limits and reset values inside the width,
every field inside its register, no two fields of a register sharing a bit.

A field is reached by its qualified name, ``"register.field"`` (`RegisterTable.field`):
that lookup is the only way to a `BoundField`, so a driver or a simulated chip cannot use
a bit that its table does not declare.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from functools import cached_property


class Access(StrEnum):
    RO = "ro"
    RW = "rw"
    WO = "wo"


@dataclass(frozen=True)
class Field:
    """Bits ``msb..lsb`` of a register (one bit when ``lsb`` is omitted).

    Parameters
    ----------
    name
        Identifier, unique within its register (``"mirror_column"``).
    msb
        Most significant bit of the field.
    lsb
        Least significant bit; None for a one-bit field.
    doc
        Meaning and encoding of the value (``"value/8 (8 = 1.0x)"``).
    """

    name: str
    msb: int
    lsb: int | None = None
    doc: str = ""

    # Cached: drivers and chips decode fields on every frame.
    @cached_property
    def shift(self) -> int:
        """Position of the least significant bit."""
        return self.msb if self.lsb is None else self.lsb

    @cached_property
    def width(self) -> int:
        return self.msb - self.shift + 1

    @cached_property
    def mask(self) -> int:
        """The field's bits in place."""
        return ((1 << self.width) - 1) << self.shift

    @cached_property
    def limit(self) -> int:
        """Largest value the field holds."""
        return (1 << self.width) - 1

    @property
    def bits(self) -> str:
        """The bits as a datasheet writes them: ``"14"`` or ``"5:0"``."""
        return str(self.msb) if self.lsb is None else f"{self.msb}:{self.lsb}"


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
    fields
        Its bit fields, where its bits have separate meanings.
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
    fields: tuple[Field, ...] = ()

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


@dataclass(frozen=True)
class BoundField:
    """A field of one register of a table: reads and writes it inside a register value."""

    register: Register
    field: Field

    @property
    def name(self) -> str:
        """The qualified name, ``"register.field"``."""
        return f"{self.register.name}.{self.field.name}"

    def get(self, word: int) -> int:
        """The field's value in a register value."""
        f = self.field
        return (word & f.mask) >> f.shift

    def put(self, word: int, value: int) -> int:
        """A register value with the field set to ``value`` (the other bits kept)."""
        f = self.field
        if not 0 <= value <= f.limit:
            raise ValueError(f"{self.name} (bits {f.bits}) = {value}; allowed 0..{f.limit}")
        return (word & ~f.mask) | value << f.shift

    @property
    def reset(self) -> int:
        """The field's value after reset."""
        return self.get(self.register.reset)


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

    def __init__(self, model: str, registers: Sequence[Register], *, address_bytes: int) -> None:
        self.model = model
        self.address_bytes = address_bytes
        self._by_name: dict[str, Register] = {}
        self._by_address: dict[int, Register] = {}
        self._fields: dict[str, BoundField] = {}
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
            self._add_fields(r)
            self._by_name[r.name] = r
            self._by_address[r.address] = r

    def _add_fields(self, r: Register) -> None:
        used = 0
        for f in r.fields:
            where = f"{self.model}: field {r.name}.{f.name} (bits {f.bits})"
            if f.lsb is not None and not 0 <= f.lsb <= f.msb:
                raise ValueError(f"{where}: lsb must be 0..msb")
            if f.msb >= r.width:
                raise ValueError(f"{where} does not fit the {r.width}-bit register")
            if f.mask & used:
                raise ValueError(f"{where} overlaps another field of {r.name}")
            bound = BoundField(r, f)
            if bound.name in self._fields:
                raise ValueError(f"{where} declared twice")
            used |= f.mask
            self._fields[bound.name] = bound

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

    def field(self, name: str) -> BoundField:
        """A declared field by its qualified name, ``"register.field"`` (KeyError if none)."""
        try:
            return self._fields[name]
        except KeyError:
            known = ", ".join(self._fields) or "none"
            raise KeyError(f"{self.model} has no field {name!r}; fields: {known}") from None

    def fields(self) -> Iterator[BoundField]:
        """Every declared field, register by register."""
        return iter(self._fields.values())

    def fields_of(self, register: str, value: int) -> dict[str, int]:
        """A value of a register decoded into its fields (empty if it declares none)."""
        r = self[register]
        return {f.name: BoundField(r, f).get(value) for f in r.fields}


@dataclass(frozen=True)
class FieldRule:
    """A register field that follows a frame parameter, written by one program function.

    The field takes the parameter's value, or, with ``mask``, 1 when the parameter has any
    of the mask's bits set and 0 otherwise (``TRIG & 4`` -> the snapshot bit).

    Parameters
    ----------
    function
        The program function that writes the register (``"window"``).
    parameter
        The frame parameter (``"FLIPH"``).
    field
        The field's qualified name (``"read_mode_2.mirror_column"``).
    mask
        Bits of the parameter that set a one-bit field; None to copy the value.
    """

    function: str
    parameter: str
    field: str
    mask: int | None = None

    def value(self, state: Mapping[str, int]) -> int:
        value = state[self.parameter]
        return value if self.mask is None else int(bool(value & self.mask))


class FieldRules:
    """The parameter -> field rules of one sensor, checked on creation.

    A register that rules touch is composed from its current value (its shadow, or its
    reset value when there is no shadow yet), so bits no rule owns keep what the chip
    has; a register named in ``from_reset`` is composed from its reset value instead
    (its other bits are constants the driver always writes).

    Parameters
    ----------
    table
        The table the fields belong to; every rule's field must be declared there.
    rules
        The rules, in the order their registers are written.
    from_reset
        Registers composed from their reset value rather than from the shadow.
    """

    def __init__(
        self,
        table: RegisterTable,
        rules: Sequence[FieldRule],
        *,
        from_reset: frozenset[str] = frozenset(),
    ) -> None:
        self.table = table
        self.rules = tuple(rules)
        self.from_reset = from_reset
        self._by_function: dict[str, list[tuple[FieldRule, BoundField]]] = {}
        for rule in self.rules:
            bound = table.field(rule.field)
            self._by_function.setdefault(rule.function, []).append((rule, bound))
        for name in from_reset:
            table[name]

    def __iter__(self) -> Iterator[FieldRule]:
        return iter(self.rules)

    @property
    def functions(self) -> frozenset[str]:
        """The program functions that have rules."""
        return frozenset(rule.function for rule in self.rules)

    def registers(
        self, function: str, state: Mapping[str, int], current: Mapping[str, int]
    ) -> dict[str, int]:
        """Values of the registers a function's rules touch, in the order of the rules."""
        out: dict[str, int] = {}
        for rule, bound in self._by_function.get(function, ()):
            register = bound.register
            if register.name not in out:
                if register.name in self.from_reset:
                    out[register.name] = register.reset
                else:
                    out[register.name] = current.get(register.name, register.reset)
            out[register.name] = bound.put(out[register.name], rule.value(state))
        return out
