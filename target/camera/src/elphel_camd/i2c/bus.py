"""The bus protocol every I2C transport implements, and the factory that opens one by URL.

A bus is anything with smbus2's ``i2c_rdwr(*msgs)``: the real ``smbus2.SMBus`` on a
Linux board, or the simulator's bus, which answers the same ``i2c_msg`` transfers from
chip models. Drivers receive a ready bus; they never open one.
"""

from __future__ import annotations

import logging
from typing import Protocol, runtime_checkable
from urllib.parse import urlparse

from smbus2 import I2cFunc, SMBus, i2c_msg

from elphel_camd.i2c.smbus_word import SMBusWordBus

log = logging.getLogger(__name__)


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
        An open ``smbus2.SMBus``; where the adapter offers SMBus word commands but no
        plain I2C transfers, a `elphel_camd.i2c.smbus_word.SMBusWordBus` over it. Which one
        is logged, and is the bus's ``mode`` (``"i2c"`` or ``"smbus-word"``).
    """
    parsed = urlparse(url)
    if parsed.scheme not in ("", "i2c"):
        raise ValueError(f"I2C bus URL {url!r}: scheme must be i2c:// or none")
    path = parsed.path or url
    if path.isdigit():
        return _transfers(SMBus(int(path)), f"/dev/i2c-{path}")
    if not path.startswith("/dev/i2c-") or not path[len("/dev/i2c-") :].isdigit():
        raise ValueError(f"I2C bus URL {url!r}: expected /dev/i2c-N")
    return _transfers(SMBus(path), path)


def _transfers(bus: SMBus, name: str) -> I2CBus:
    """The bus itself if its adapter runs plain I2C, else word commands over SMBus."""
    funcs = bus.funcs
    words = I2cFunc.SMBUS_READ_WORD_DATA | I2cFunc.SMBUS_WRITE_WORD_DATA
    if funcs & I2cFunc.I2C or funcs & words != words:
        log.info("%s: plain I2C transfers", name)
        bus.mode = "i2c"  # type: ignore[attr-defined]
        return bus
    log.info("%s: the adapter offers only SMBus; using SMBus word transfers", name)
    return SMBusWordBus(bus, name=name)
