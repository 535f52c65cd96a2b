"""Register access over an I2C bus: 8- or 16-bit register addresses, 16-bit big-endian data.

Reads are a combined transfer (write the register address, repeated start, read), as the
Aptina sensors and the Lepton CCI expect. NAKs are retried a few times and then surface as
`I2CError` naming the bus, device and register; a retry that went through is logged once.
"""

from __future__ import annotations

import logging

from smbus2 import i2c_msg

from elphel_camd.errors import I2CError
from elphel_camd.i2c.bus import I2CBus

log = logging.getLogger(__name__)


class RegisterIO:
    """Read and write 16-bit registers of one device on one bus.

    Parameters
    ----------
    bus
        An open bus (``smbus2.SMBus`` or a simulated one).
    address
        7-bit device address.
    reg_bytes
        Width of the register address on the wire: 1 (MT9P006) or 2 (MT9F002, Lepton).
    bus_name
        Name used in error messages (e.g. ``"port 0"`` or ``"/dev/i2c-1"``).
    retries
        How many times a NAKed transfer is tried again before it is reported.
    """

    def __init__(
        self,
        bus: I2CBus,
        address: int,
        *,
        reg_bytes: int,
        bus_name: str = "i2c",
        retries: int = 2,
    ) -> None:
        if reg_bytes not in (1, 2):
            raise ValueError(f"reg_bytes={reg_bytes!r}; allowed: 1 or 2")
        if not 0x03 <= address <= 0x77:
            raise ValueError(f"address=0x{address:02x}; allowed: 0x03..0x77 (7-bit)")
        self.bus = bus
        self.address = address
        self.reg_bytes = reg_bytes
        self.bus_name = bus_name
        self.retries = retries
        self.nak_count = 0

    def _reg_address(self, register: int) -> bytes:
        limit = 1 << (8 * self.reg_bytes)
        if not 0 <= register < limit:
            raise ValueError(f"register=0x{register:x}; allowed: 0..0x{limit - 1:x}")
        return register.to_bytes(self.reg_bytes, "big")

    def _transfer(self, register: int, *msgs: i2c_msg) -> None:
        """Do one transfer, trying a NAKed one again up to ``retries`` times.

        A transfer that failed and then went through is logged once (a warning: nothing
        else will ever tell of it). One that fails every attempt raises `I2CError` and
        logs nothing: whoever catches it reports it, or knows it is expected (a probe
        for a sensor that is not there).
        """
        failures: list[OSError] = []
        for attempt in range(self.retries + 1):
            try:
                self.bus.i2c_rdwr(*msgs)
            except OSError as e:
                self.nak_count += 1
                failures.append(e)
                log.debug(
                    "%s: %s (attempt %d of %d)",
                    self._where(register),
                    e,
                    attempt + 1,
                    self.retries + 1,
                )
                continue
            if failures:
                log.warning(
                    "%s: went through at attempt %d of %d, after: %s",
                    self._where(register),
                    attempt + 1,
                    self.retries + 1,
                    failures[-1],
                )
            return
        raise I2CError(
            f"{self._where(register)}: transfer failed {self.retries + 1} times: {failures[-1]}",
            bus=self.bus_name,
            address=self.address,
            register=register,
        ) from failures[-1]

    def _where(self, register: int) -> str:
        return f"{self.bus_name}: device 0x{self.address:02x} register 0x{register:x}"

    def read(self, register: int, count: int = 1) -> list[int]:
        """Read ``count`` consecutive 16-bit words starting at ``register``."""
        if count < 1:
            raise ValueError(f"count={count}; allowed: >= 1")
        write = i2c_msg.write(self.address, self._reg_address(register))
        read = i2c_msg.read(self.address, 2 * count)
        self._transfer(register, write, read)
        data = bytes(read)
        words = [int.from_bytes(data[i : i + 2], "big") for i in range(0, len(data), 2)]
        log.debug("%s: 0x%02x read 0x%x -> %s", self.bus_name, self.address, register, words)
        return words

    def read_word(self, register: int) -> int:
        """Read one 16-bit register."""
        return self.read(register, 1)[0]

    def write(self, register: int, *words: int) -> None:
        """Write consecutive 16-bit words starting at ``register`` in one transfer."""
        if not words:
            raise ValueError("write needs at least one word")
        payload = bytearray(self._reg_address(register))
        for w in words:
            if not 0 <= w <= 0xFFFF:
                raise ValueError(f"value={w!r} for register 0x{register:x}; allowed: 0..0xffff")
            payload += w.to_bytes(2, "big")
        log.debug("%s: 0x%02x write 0x%x <- %s", self.bus_name, self.address, register, words)
        self._transfer(register, i2c_msg.write(self.address, bytes(payload)))
