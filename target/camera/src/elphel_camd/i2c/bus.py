"""The bus protocol every I2C transport implements, and the factory that opens one by URL.

A bus is anything with smbus2's ``i2c_rdwr(*msgs)``: the real ``smbus2.SMBus`` on a
Linux board, or the simulator's bus, which answers the same ``i2c_msg`` transfers from
chip models. Drivers receive a ready bus; they never open one.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable
from urllib.parse import urlparse

from smbus2 import SMBus, i2c_msg


@runtime_checkable
class I2CBus(Protocol):
    """What a driver needs from a bus: combined write/read transfers with repeated start."""

    def i2c_rdwr(self, *i2c_msgs: i2c_msg) -> None:
        """Run the messages as one transaction (one STOP at the end); raise OSError on NAK."""
        ...


def open_bus(url: str) -> I2CBus:
    """Open an I2C bus from a URL.

    Parameters
    ----------
    url
        ``i2c:///dev/i2c-N`` or ``/dev/i2c-N`` or a bare bus number ``N``.

    Returns
    -------
    I2CBus
        An open ``smbus2.SMBus``.
    """
    parsed = urlparse(url)
    if parsed.scheme not in ("", "i2c"):
        raise ValueError(f"I2C bus URL {url!r}: scheme must be i2c:// or none")
    path = parsed.path or url
    if path.isdigit():
        return SMBus(int(path))
    if not path.startswith("/dev/i2c-") or not path[len("/dev/i2c-") :].isdigit():
        raise ValueError(f"I2C bus URL {url!r}: expected /dev/i2c-N")
    return SMBus(path)
