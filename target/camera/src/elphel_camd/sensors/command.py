"""Sensors driven by commands rather than a register file (the Lepton's CCI).

A command-protocol sensor has attributes it GETs and SETs and functions it RUNs, named in
its command table. Like a register-file driver it keeps a shadow, of the attribute values
it last set, and sends a SET only when the value differs; after a failed SET the shadow
is dropped, so the next one is sent.
"""

from __future__ import annotations

from typing import ClassVar

from elphel_camd.i2c.regio import RegisterIO
from elphel_camd.sensors import cci
from elphel_camd.sensors.base import SensorDriver
from elphel_camd.sensors.register_file import InterfaceRegisters


class CommandSensor(SensorDriver):
    """A driver that reaches its chip through CCI commands (`elphel_camd.sensors.cci`).

    Parameters
    ----------
    io
        Register access to the CCI (16-bit register addresses).
    timeout_s
        How long a command may keep the chip busy.
    """

    commands: ClassVar[dict[str, cci.Command]] = cci.COMMANDS

    def __init__(self, io: RegisterIO, *, timeout_s: float = 1.0) -> None:
        self.io = io
        self.cci = cci.CCI(io, timeout_s=timeout_s)
        self.settings: dict[str, int] = {}  # attributes as last set (their shadow)
        # The CCI's own registers, for the admin's raw register view.
        self.interface_registers = InterfaceRegisters(io, cci.REGISTERS)

    def read_chip_id(self) -> int:
        """The CCI status word now (boot and busy bits, error code)."""
        return self.cci.status()

    def set_attribute(self, name: str, value: int) -> bool:
        """SET an attribute unless the last value set is the same; return whether sent."""
        if self.settings.get(name) == value:
            return False
        self.settings.pop(name, None)
        self.cci.set_value(self.commands[name], value)
        self.settings[name] = value
        return True

    def get_attribute(self, name: str) -> int:
        """GET an attribute now (and refresh its shadow if it can be set)."""
        command = self.commands[name]
        value = self.cci.get_value(command)
        if command.kinds != frozenset({cci.CommandType.GET}):
            self.settings[name] = value
        return value

    def run_command(self, name: str) -> None:
        """RUN a command; raises `LeptonError` if the chip answers with an error."""
        self.cci.run(self.commands[name])
