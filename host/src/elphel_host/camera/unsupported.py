"""Features a camera backend lacks, each raising `UnsupportedError` that names it.

A stock NC393 has no event stream and no raw register access through its web server:
`NoEventsNoRegisters` gives a backend the `CameraInterface` methods for both, refusing plainly.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, NoReturn

from elphel_host.camera.events import CameraEvent
from elphel_host.errors import UnsupportedError

_REGISTERS = "raw sensor registers: not available through a stock NC393's parsedit.php"


class NoEventsNoRegisters:
    """``events`` and the raw-register methods of a backend that has neither."""

    def events(self, *args: Any, **kwargs: Any) -> Iterator[CameraEvent]:
        """Unsupported: a stock NC393 has no event stream (whatever is asked of it)."""
        _unsupported("events: a stock NC393 has no event stream (poll frame() instead)")

    def registers(self, port: int = 0) -> list[dict[str, Any]]:
        """Unsupported: raw sensor registers are elphel-camd's (its register tables)."""
        _unsupported(_REGISTERS)

    def register(self, address: int, *, port: int = 0) -> dict[str, Any]:
        """Unsupported (see `registers`)."""
        _unsupported(_REGISTERS)

    def set_register(self, address: int, value: int, *, port: int = 0) -> dict[str, Any]:
        """Unsupported (see `registers`)."""
        _unsupported(_REGISTERS)


def _unsupported(what: str) -> NoReturn:
    raise UnsupportedError(what)
