"""The FLIR Lepton's Command and Control Interface (CCI) over I2C.

Facts: shared/reference/sensors.md section 5.1. A command is issued through a few 16-bit
registers: wait until the status register's BUSY bit clears, write the data words (SET),
the data length in words, then the command word ``module << 8 | command | type`` (type 0
GET, 1 SET, 2 RUN; OEM and RAD commands carry the protection bit 0x4000); wait for BUSY to
clear again and read the signed error code in status bits 15:8; a GET then reads the data
words. Multi-word attributes are sent least-significant word first; enums are 32-bit.

The CCI's registers are declared once as a table (`REGISTERS`, with the status bits as
fields), the commands once as data (`COMMANDS`): name, base id and attribute length.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import TypeVar

from elphel_camd.errors import LeptonError
from elphel_camd.i2c.regio import RegisterIO
from elphel_camd.sensors.registers import Access, Field, Register, RegisterTable

DATA_WORDS = 16  # DATA0..DATA15; longer attributes would need the block buffers

# The CCI's own registers (reference 5.1): the transport of commands, 16-bit addresses.
REGISTERS = RegisterTable(
    "LEPTON35 CCI",
    [
        Register("power", 0x0000, 0, doc="host power switch while in standby/off"),
        Register(
            "status",
            0x0002,
            0x0006,  # booted from ROM, boot complete, not busy, no error
            Access.RO,
            doc="bit 0 BUSY, bit 1 boot mode, bit 2 booted, bits 15:8 signed error code",
            fields=(
                Field("busy", 0, doc="1 while a command runs"),
                Field("boot_mode", 1, doc="1 = booted from internal ROM"),
                Field("booted", 2, doc="1 = boot complete"),
                Field("reserved", 7, 3, doc="always 0"),
                Field("error", 15, 8, doc="signed error code of the last command (0 = ok)"),
            ),
        ),
        Register("command", 0x0004, 0, doc="module << 8 | command | type (GET/SET/RUN)"),
        Register(
            "data_length", 0x0006, 0, unit="words", doc="attribute length of the next command"
        ),
        *(
            Register(
                f"data{i}",
                0x0008 + 2 * i,
                0,
                doc=f"data word {i} (word {i} of an attribute, least significant first)",
            )
            for i in range(DATA_WORDS)
        ),
        Register("data_crc", 0x0028, 0, Access.RO, doc="CRC16 of the data (0: none)"),
    ],
    address_bytes=2,
)

REG_POWER = REGISTERS["power"].address
REG_STATUS = REGISTERS["status"].address
REG_COMMAND = REGISTERS["command"].address
REG_DATA_LENGTH = REGISTERS["data_length"].address
REG_DATA0 = REGISTERS["data0"].address
REG_DATA_CRC = REGISTERS["data_crc"].address

# Status register bits, from its fields.
STATUS_BUSY = REGISTERS.field("status.busy").field.mask
STATUS_BOOT_MODE = REGISTERS.field("status.boot_mode").field.mask
STATUS_BOOTED = REGISTERS.field("status.booted").field.mask
STATUS_RESERVED = REGISTERS.field("status.reserved").field.mask
STATUS_READY = STATUS_BOOT_MODE | STATUS_BOOTED  # booted and not busy
_ERROR = REGISTERS.field("status.error")

PROTECTION_BIT = 0x4000  # set on OEM and RAD commands


class CommandType(IntEnum):
    GET = 0
    SET = 1
    RUN = 2


class Module(IntEnum):
    AGC = 0x1
    SYS = 0x2
    VID = 0x3
    OEM = 0x8
    RAD = 0xE


# Error codes of the FLIR SDK's result type (a signed byte in status bits 15:8). The
# reference gives only their encoding; the names are the SDK's.
ERROR_NAMES = {
    -1: "error",
    -2: "not ready",
    -3: "range error",
    -4: "checksum error",
    -5: "bad argument pointer",
    -6: "data size error",
    -7: "undefined function",
    -8: "function not supported",
}


def command_id(module: Module, command: int, kind: CommandType) -> int:
    """The command word: module, command (a multiple of 4 below 0x100) and type."""
    if command & 0x3 or not 0 <= command < 0x100:
        raise ValueError(f"command=0x{command:x}; allowed: 0..0xfc, a multiple of 4")
    protection = PROTECTION_BIT if module in (Module.OEM, Module.RAD) else 0
    return protection | module << 8 | command | kind


@dataclass(frozen=True)
class Command:
    """One CCI command (an attribute or a runnable function) of the Lepton.

    Parameters
    ----------
    name
        Identifier used in messages.
    module
        The CCI module.
    command
        Command number within the module (bits 7:2 of the command word).
    words
        Attribute length in 16-bit words (0 for a RUN-only command).
    kinds
        The types the command accepts.
    unit
        Unit of the attribute value.
    doc
        Meaning.
    """

    name: str
    module: Module
    command: int
    words: int
    kinds: frozenset[CommandType]
    unit: str = ""
    doc: str = ""

    @property
    def base(self) -> int:
        """The GET command word (protection bit included)."""
        return command_id(self.module, self.command, CommandType.GET)

    def id(self, kind: CommandType) -> int:
        if kind not in self.kinds:
            allowed = ", ".join(k.name for k in sorted(self.kinds))
            raise ValueError(f"Lepton command {self.name} cannot {kind.name}; allowed: {allowed}")
        return self.base | kind


_GS = frozenset({CommandType.GET, CommandType.SET})
_G = frozenset({CommandType.GET})
_R = frozenset({CommandType.RUN})


def _table(commands: Sequence[Command]) -> dict[str, Command]:
    by_name: dict[str, Command] = {}
    bases: dict[int, str] = {}
    for c in commands:
        if c.name in by_name:
            raise ValueError(f"Lepton command {c.name!r} declared twice")
        if c.base in bases:
            raise ValueError(f"Lepton commands {c.name} and {bases[c.base]} share 0x{c.base:04x}")
        if not 0 <= c.words <= DATA_WORDS or (CommandType.RUN in c.kinds) != (c.words == 0):
            raise ValueError(f"Lepton command {c.name}: {c.words} words for {set(c.kinds)}")
        by_name[c.name] = c
        bases[c.base] = c.name
    return by_name


# Key commands (reference 5.2).
COMMANDS: dict[str, Command] = _table(
    [
        Command("AGC_ENABLE", Module.AGC, 0x00, 2, _GS, "enum", "0 disabled, 1 enabled"),
        Command("SYS_PING", Module.SYS, 0x00, 0, _R, doc="is the camera answering"),
        Command("SYS_UPTIME", Module.SYS, 0x0C, 2, _G, "ms", "time since power-up"),
        Command("SYS_AUX_TEMPERATURE", Module.SYS, 0x10, 1, _G, "0.01 K", "AUX temperature"),
        Command("SYS_FPA_TEMPERATURE", Module.SYS, 0x14, 1, _G, "0.01 K", "FPA temperature"),
        Command("SYS_TELEMETRY_ENABLE", Module.SYS, 0x18, 2, _GS, "enum", "0 off, 1 on"),
        Command("SYS_TELEMETRY_LOCATION", Module.SYS, 0x1C, 2, _GS, "enum", "0 header, 1 footer"),
        Command("SYS_RUN_FFC", Module.SYS, 0x40, 0, _R, doc="flat-field correction now"),
        Command(
            "OEM_GPIO_MODE",
            Module.OEM,
            0x54,
            2,
            _GS,
            "enum",
            "0 GPIO, 1 I2C master, 2/3 SPI master, 4 SPI slave, 5 VSYNC on GPIO3",
        ),
        Command("RAD_ENABLE", Module.RAD, 0x10, 2, _GS, "enum", "radiometry 0 off, 1 on"),
        Command("RAD_TLINEAR_ENABLE", Module.RAD, 0xC0, 2, _GS, "enum", "TLinear 0 off, 1 on"),
        Command(
            "RAD_TLINEAR_RESOLUTION", Module.RAD, 0xC4, 2, _GS, "enum", "0 = 0.1 K, 1 = 0.01 K"
        ),
    ]
)


def command_name(word: int) -> str:
    """The name of a command word, for messages."""
    for c in COMMANDS.values():
        if c.base == word & ~0x3:
            return f"{c.name} {CommandType(word & 0x3).name}"
    return "unknown command"


def words_of(value: int, words: int) -> list[int]:
    """Split a value into 16-bit words, least significant first (the CCI word order)."""
    if not 0 <= value < 1 << (16 * words):
        raise ValueError(f"value={value}; allowed: 0..{(1 << (16 * words)) - 1}")
    return [(value >> (16 * i)) & 0xFFFF for i in range(words)]


def value_of(words: Sequence[int]) -> int:
    """Join 16-bit words sent least significant first."""
    return sum(w << (16 * i) for i, w in enumerate(words))


def error_code(status: int) -> int:
    """The signed error code in status bits 15:8 (0 = success)."""
    code = _ERROR.get(status)
    return code - 0x100 if code & 0x80 else code


class CCITimeoutError(LeptonError, TimeoutError):
    """The Lepton stayed busy (or did not finish booting) past the timeout."""


E = TypeVar("E", bound=LeptonError)


class CCI:
    """Issues CCI commands to one Lepton.

    Parameters
    ----------
    io
        Register access to the Lepton (address 0x2A, 16-bit register addresses).
    timeout_s
        How long to poll BUSY before giving up.
    poll_interval_s
        Pause between status polls (Elphel polls every 1 ms).
    sleep, clock
        Injected for tests; ``time.sleep`` and ``time.monotonic`` by default.
    """

    def __init__(
        self,
        io: RegisterIO,
        *,
        timeout_s: float = 1.0,
        poll_interval_s: float = 0.001,
        sleep: Callable[[float], None] = time.sleep,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.io = io
        self.timeout_s = timeout_s
        self.poll_interval_s = poll_interval_s
        self._sleep = sleep
        self._clock = clock

    def status(self) -> int:
        return self.io.read_word(REG_STATUS)

    def _error(
        self, kind: type[E], detail: str, *, word: int, register: int, code: int | None
    ) -> E:
        """An error naming the bus, the Lepton's address, the command word and the code."""
        return kind(
            f"{self.io.bus_name}: Lepton 0x{self.io.address:02x} {detail}",
            bus=self.io.bus_name,
            address=self.io.address,
            register=register,
            command=word,
            code=code,
        )

    def _timeout(self, what: str, word: int, status: int) -> CCITimeoutError:
        detail = f"{what} (status 0x{status:04x}) after {self.timeout_s} s"
        return self._error(CCITimeoutError, detail, word=word, register=REG_STATUS, code=None)

    def wait_ready(self, word: int = 0, *, booted: bool = False) -> int:
        """Poll the status register until BUSY clears (and, if asked, boot completed).

        Returns the last status read. Raises `CCITimeoutError` past ``timeout_s``.
        """
        deadline = self._clock() + self.timeout_s
        while True:
            status = self.status()
            ready = not status & STATUS_BUSY
            if booted:
                ready = ready and status & STATUS_READY == STATUS_READY
            if ready:
                return status
            if self._clock() >= deadline:
                what = (
                    "did not finish booting"
                    if booted
                    else f"stayed busy before/after {command_name(word)} (0x{word:04x})"
                )
                raise self._timeout(what, word, status)
            self._sleep(self.poll_interval_s)

    def _check(self, word: int, status: int) -> None:
        code = error_code(status)
        if code:
            meaning = ERROR_NAMES.get(code, "unknown error")
            detail = f"refused {command_name(word)} (0x{word:04x}): error {code} ({meaning})"
            raise self._error(LeptonError, detail, word=word, register=REG_COMMAND, code=code)

    def _issue(self, word: int) -> None:
        self.io.write(REG_COMMAND, word)
        self._check(word, self.wait_ready(word))

    def get(self, command: Command) -> list[int]:
        """GET an attribute: its data words, least significant first."""
        word = command.id(CommandType.GET)
        self.wait_ready(word)
        self.io.write(REG_DATA_LENGTH, command.words)
        self._issue(word)
        return self.io.read(REG_DATA0, command.words)

    def set(self, command: Command, data: Sequence[int]) -> None:
        """SET an attribute from its data words, least significant first."""
        word = command.id(CommandType.SET)
        if len(data) != command.words:
            raise ValueError(f"Lepton {command.name} takes {command.words} words; got {len(data)}")
        self.wait_ready(word)
        self.io.write(REG_DATA0, *data)
        self.io.write(REG_DATA_LENGTH, command.words)
        self._issue(word)

    def run(self, command: Command) -> None:
        """RUN a command (no data)."""
        word = command.id(CommandType.RUN)
        self.wait_ready(word)
        self.io.write(REG_DATA_LENGTH, 0)
        self._issue(word)

    def get_value(self, command: Command) -> int:
        """GET an attribute as one unsigned integer (enums are 32-bit)."""
        return value_of(self.get(command))

    def set_value(self, command: Command, value: int) -> None:
        """SET an attribute from one unsigned integer."""
        self.set(command, words_of(value, command.words))
