"""A simulated I2C bus that answers smbus2 ``i2c_msg`` transfers from chip models.

It has the same ``i2c_rdwr(*msgs)`` as ``smbus2.SMBus``, so the daemon's real register
code runs on it unchanged. A device that does not answer (absent, or a NAK injected with
``sim_nak``) raises ``OSError(EREMOTEIO)``, as the Linux i2c-dev driver does.
"""

from __future__ import annotations

import ctypes
import errno
import threading
from typing import Protocol

from smbus2 import i2c_msg

I2C_M_RD = 0x0001


class SimDevice(Protocol):
    """A simulated I2C target: receives written bytes, produces bytes to read."""

    def on_write(self, data: bytes) -> None:
        """Handle one write message (register address, then data)."""
        ...

    def on_read(self, length: int) -> bytes:
        """Return ``length`` bytes for a read message."""
        ...

    def on_stop(self) -> None:
        """End of the combined transaction (STOP condition)."""
        ...


class SimI2CBus:
    """Devices by 7-bit address, with fault hooks.

    Parameters
    ----------
    name
        Shown in error messages.
    """

    def __init__(self, name: str = "sim-i2c") -> None:
        self.name = name
        self.devices: dict[int, SimDevice] = {}
        self.transfers: list[tuple[int, str, bytes]] = []  # (address, "w"/"r", bytes) log
        self.log_transfers = False
        self._nak_remaining = 0
        self._nak_address: int | None = None
        self._stuck = False
        self.lock = threading.RLock()

    def attach(self, address: int, device: SimDevice) -> None:
        self.devices[address] = device

    # -- fault hooks ---------------------------------------------------------------------

    def sim_nak(self, count: int = 1, *, address: int | None = None) -> None:
        """NAK the next ``count`` transfers (to ``address`` only, if given)."""
        self._nak_remaining = count
        self._nak_address = address

    def sim_stuck(self, stuck: bool = True) -> None:
        """A stuck bus (SDA held low): every transfer fails until released."""
        self._stuck = stuck

    @property
    def sim_naks_pending(self) -> tuple[int, int | None]:
        """NAKs still to come from `sim_nak` and the address they are for (None: any)."""
        return self._nak_remaining, self._nak_address

    # -- the smbus2 interface ------------------------------------------------------------

    def i2c_rdwr(self, *i2c_msgs: i2c_msg) -> None:
        with self.lock:
            if self._stuck:
                raise OSError(errno.ETIMEDOUT, f"{self.name}: bus stuck (SDA low)")
            first = i2c_msgs[0].addr if i2c_msgs else None
            if self._nak_remaining and self._nak_address in (None, first):
                self._nak_remaining -= 1
                raise OSError(errno.EREMOTEIO, f"{self.name}: injected NAK from 0x{first:02x}")
            touched: list[SimDevice] = []
            try:
                for msg in i2c_msgs:
                    device = self.devices.get(msg.addr)
                    if device is None:
                        raise OSError(
                            errno.EREMOTEIO, f"{self.name}: no device at 0x{msg.addr:02x}"
                        )
                    if device not in touched:
                        touched.append(device)
                    if msg.flags & I2C_M_RD:
                        data = device.on_read(msg.len)
                        if len(data) != msg.len:
                            raise OSError(
                                errno.EIO,
                                f"{self.name}: device returned {len(data)} of {msg.len} bytes",
                            )
                        ctypes.memmove(msg.buf, data, msg.len)
                        if self.log_transfers:
                            self.transfers.append((msg.addr, "r", data))
                    else:
                        data = bytes(msg)
                        device.on_write(data)
                        if self.log_transfers:
                            self.transfers.append((msg.addr, "w", data))
            finally:
                for device in touched:
                    device.on_stop()
