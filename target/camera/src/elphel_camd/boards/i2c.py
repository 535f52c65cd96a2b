"""The built-in ``i2c`` board: sensors on Linux /dev/i2c-N buses, one bus per port.

It has no image path and no frame syncs, so parameter changes apply at once.
"""

from __future__ import annotations

from collections.abc import Mapping

from elphel_camd.boards.base import Frame, FrameSync
from elphel_camd.errors import CaptureUnavailableError
from elphel_camd.i2c.bus import I2CBus, open_bus


class I2CBoard:
    """Sensors on Linux I2C buses, one bus per port; images come from elsewhere.

    Parameters
    ----------
    bus_urls
        One bus URL per port, e.g. ``["/dev/i2c-0", "/dev/i2c-1"]``.
    """

    name = "i2c"
    capabilities: frozenset[str] = frozenset()

    def __init__(self, bus_urls: list[str]) -> None:
        if not bus_urls:
            raise ValueError("the i2c board needs at least one bus (e.g. --bus /dev/i2c-0)")
        self._buses = {port: open_bus(url) for port, url in enumerate(bus_urls)}

    def buses(self) -> Mapping[int, I2CBus]:
        return self._buses

    def on_frame_sync(self, callback: FrameSync) -> None:
        """A bare I2C board sees no frame syncs; the callback is never called."""

    def program(self, port: int, function: str, state: Mapping[str, int]) -> None:
        """No FPGA: nothing beyond the sensor to program."""

    def capture(self, port: int, *, frame: int | None = None, timeout_s: float = 10.0) -> Frame:
        raise CaptureUnavailableError(
            f"port {port}: the i2c board controls sensors only; "
            "it has no image path to capture from"
        )

    def close(self) -> None:
        for bus in self._buses.values():
            close = getattr(bus, "close", None)
            if close is not None:
                close()
