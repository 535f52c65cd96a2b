"""What the host needs of a camera, whichever backend serves it: the `CameraInterface` protocol.

Two backends keep it: `~elphel_host.camera.client.CameraClient` (elphel-camd over REST)
and `~elphel_host.camera.nc393.client.NC393Client` (a stock NC393: parsedit.php and imgsrv).
`elphel_host.camera.connect` picks one from the camera URL. A backend that lacks a
feature raises `~elphel_host.errors.UnsupportedError` naming it.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import AbstractContextManager
from types import TracebackType
from typing import Any, Protocol, Self

from elphel_host.camera.events import CameraEvent
from elphel_host.camera.frames import CapturedBurst, CapturedFrame
from elphel_host.camera.staging import Applied


class CameraInterface(Protocol):
    """A camera with sensor ports, frame parameters and captures (docs/camera-backends.md)."""

    url: str

    def info(self) -> dict[str, Any]:
        """Board, software and every port with its sensor (``None`` for an empty port)."""
        ...

    def params(self, port: int = 0, *, frame: int | None = None) -> dict[str, int]:
        """Parameters in effect now (or for frame ``frame``, where the backend keeps them)."""
        ...

    def set_params(
        self,
        changes: Mapping[str, int],
        *,
        port: int = 0,
        frame: int | None = None,
        ahead: int | None = None,
    ) -> Applied:
        """Change parameters at frame ``frame`` or ``ahead`` frames on; the frame they take."""
        ...

    def frame(self, port: int = 0) -> dict[str, int]:
        """``port``, ``frame`` and ``timestamp_ns`` of the port's current frame."""
        ...

    def staged(
        self, changes: Mapping[str, int] | Mapping[int, Mapping[str, int]], *, port: int = 0
    ) -> AbstractContextManager[dict[int, Applied]]:
        """Settings for a block, the previous ones back on exit (see `Staging.staged`)."""
        ...

    def capture(self, port: int = 0, *, frame: int | None = None) -> CapturedFrame:
        """The next frame of a port as a 16-bit TIFF with its metadata (or frame ``frame``)."""
        ...

    def burst(self, count: int, *, port: int = 0, frame: int | None = None) -> CapturedBurst:
        """``count`` consecutive frames."""
        ...

    def registers(self, port: int = 0) -> list[dict[str, Any]]:
        """The sensor's register table (raw access)."""
        ...

    def register(self, address: int, *, port: int = 0) -> dict[str, Any]:
        """Read one raw sensor register."""
        ...

    def set_register(self, address: int, value: int, *, port: int = 0) -> dict[str, Any]:
        """Write one raw sensor register."""
        ...

    def events(
        self,
        types: tuple[str, ...] = ("frame", "params", "error"),
        *,
        port: int | None = None,
        count: int | None = None,
    ) -> Iterator[CameraEvent]:
        """Follow the camera's events."""
        ...

    def close(self) -> None:
        """Release the connections (idempotent)."""
        ...

    def __enter__(self) -> Self: ...

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None: ...
