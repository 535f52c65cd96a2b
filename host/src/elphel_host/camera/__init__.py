"""Camera clients: one interface (`Camera`), two backends picked by the URL (`connect`).

``http(s)://HOST:PORT`` is elphel-camd (`CameraClient`), ``nc393://HOST[:HTTP_PORT]
[?imgsrv=BASE]`` a stock NC393 (`elphel_host.camera.nc393.NC393Client`). Before this,
``Camera`` was an older name of `CameraClient`; it is now the interface both keep.
"""

from __future__ import annotations

from elphel_host.camera.backends import connect
from elphel_host.camera.client import (
    Applied,
    CameraClient,
    CameraHTTPError,
    CameraUnauthorizedError,
)
from elphel_host.camera.events import CameraEvent
from elphel_host.camera.frames import Burst, CapturedBurst, CapturedFrame, PhotoFinish
from elphel_host.camera.protocol import Camera as Camera
from elphel_host.errors import UnsupportedError

__all__ = [
    "Applied",
    "Burst",
    "Camera",
    "CameraClient",
    "CameraEvent",
    "CameraHTTPError",
    "CameraUnauthorizedError",
    "CapturedBurst",
    "CapturedFrame",
    "PhotoFinish",
    "UnsupportedError",
    "connect",
]
