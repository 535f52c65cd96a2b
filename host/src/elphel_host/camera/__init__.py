"""Camera clients: one interface (`CameraInterface`), two backends picked by the URL (`connect`).

``http(s)://HOST:PORT`` is elphel-camd (`CameraClient`), ``nc393://HOST[:HTTP_PORT]
[?imgsrv=BASE]`` a stock NC393 (`elphel_host.camera.nc393.NC393Client`). ``Camera``, the
client's name before 0.2, still gives `CameraClient` (with a DeprecationWarning).
"""

from __future__ import annotations

import warnings
from typing import Any

from elphel_host.camera.backends import connect
from elphel_host.camera.client import (
    Applied,
    CameraClient,
    CameraHTTPError,
    CameraUnauthorizedError,
)
from elphel_host.camera.events import CameraEvent
from elphel_host.camera.frames import Burst, CapturedBurst, CapturedFrame, PhotoFinish
from elphel_host.camera.protocol import CameraInterface
from elphel_host.errors import UnsupportedError

__all__ = [
    "Applied",
    "Burst",
    "CameraClient",
    "CameraEvent",
    "CameraHTTPError",
    "CameraInterface",
    "CameraUnauthorizedError",
    "CapturedBurst",
    "CapturedFrame",
    "PhotoFinish",
    "UnsupportedError",
    "connect",
]


def __getattr__(name: str) -> Any:
    # `Camera` was the client's name before 0.2; scripts that import it keep working.
    if name == "Camera":
        warnings.warn(
            "elphel_host.camera.Camera is now CameraClient (or connect(url) for any backend)",
            DeprecationWarning,
            stacklevel=2,
        )
        return CameraClient
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
