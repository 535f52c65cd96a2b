"""The parameter-model contract every sensor driver keeps with the sequencer and the service.

A driver turns a port's full parameter state into writes to the chip, one program
function at a time (`program`), and says how many frames ahead each function must be
issued (`latency`). How it reaches the chip is its own: a register-file sensor
(`elphel_camd.sensors.register_file.RegisterFileSensor`: a table of registers with
shadows and bit fields) or a command-protocol sensor
(`elphel_camd.sensors.command.CommandSensor`: the Lepton's CCI commands). Neither
pretends to be the other.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import Any, ClassVar

from elphel_camd.errors import UnsupportedError
from elphel_camd.i2c.bus import I2CBus
from elphel_camd.params import TRIG_SNAPSHOT

State = dict[str, int]


#: The window, orientation and exposure parameters every image sensor's driver writes.
IMAGE_PARAMS = (
    "WOI_LEFT",
    "WOI_TOP",
    "WOI_WIDTH",
    "WOI_HEIGHT",
    "FLIPH",
    "FLIPV",
    "EXPOS",
    "VEXPOS",
)


class SensorDriver(ABC):
    """What the sequencer and the service use of a driver: identity and parameter model.

    A driver receives a ready `elphel_camd.i2c.regio.RegisterIO`; it never opens a bus.
    Subclasses set the class attributes that identify the model.
    """

    model: ClassVar[str]
    i2c_address: ClassVar[int]
    sensor_code: ClassVar[int]
    bayer: ClassVar[str | None]
    bits: ClassVar[int]
    # Frames before the target frame at which each program function's writes are issued:
    # (free-running, snapshot). Functions not listed write nothing on this sensor.
    ahead: ClassVar[Mapping[str, tuple[int, int]]]
    # Parameters this sensor accepts writes to; others are rejected with UnsupportedError.
    writable: ClassVar[frozenset[str]]

    @classmethod
    @abstractmethod
    def probe(cls, bus: I2CBus, *, bus_name: str) -> SensorDriver | None:
        """Return a driver if this model answers on the bus, else None."""

    @abstractmethod
    def read_chip_id(self) -> int:
        """Read the chip's identity now (one transfer; raises I2CError if it does not answer)."""

    def identity(self) -> dict[str, Any]:
        """Model, chip id read now, I2C address and what the model delivers."""
        return {
            "model": self.model,
            "chip_id": self.read_chip_id(),
            "i2c_address": self.i2c_address,
            "sensor_code": self.sensor_code,
            "bayer": self.bayer,
            "bits": self.bits,
        }

    def latency(self, function: str, state: Mapping[str, int]) -> int:
        """Frames ahead a function's writes must be issued in this state's trigger mode."""
        free_run, snapshot = self.ahead[function]
        return snapshot if state.get("TRIG", 0) & TRIG_SNAPSHOT else free_run

    def check_writable(self, names: Mapping[str, int]) -> None:
        for name in names:
            if name not in self.writable:
                raise UnsupportedError(f"{self.model} does not support setting {name}")

    def actual_gains(self, state: Mapping[str, int]) -> dict[str, int]:
        """Gains the chip really applies (16.16), where they differ from the request."""
        return {}

    @abstractmethod
    def init(self) -> None:
        """Bring the chip to a known state."""

    @abstractmethod
    def program(self, function: str, state: Mapping[str, int]) -> list[str]:
        """Write what one program function needs for a state; return the names written."""

    @abstractmethod
    def defaults(self) -> State:
        """The parameter state after init."""

    @abstractmethod
    def normalize(self, state: Mapping[str, int], changed: frozenset[str]) -> State:
        """Check a whole state (raise ParameterRangeError) and fill its derived values."""

    @abstractmethod
    def frame_period_s(self, state: Mapping[str, int]) -> float:
        """Free-running frame period of the sensor in a state."""
