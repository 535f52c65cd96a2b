"""Camera clients: one interface (`CameraInterface`), two backends picked by the URL (`connect`).

``http(s)://HOST:PORT`` is elphel-camd (`CameraClient`), ``nc393://HOST[:HTTP_PORT]
[?imgsrv=BASE]`` a stock NC393 (`elphel_host.camera.nc393.client.NC393Client`).
"""

from __future__ import annotations

from elphel_host.camera.backends import connect
from elphel_host.camera.client import CameraClient, CameraHTTPError, CameraUnauthorizedError
from elphel_host.camera.events import CameraEvent
from elphel_host.camera.frames import CapturedBurst, CapturedFrame, PhotoFinish
from elphel_host.camera.protocol import CameraInterface
from elphel_host.camera.staging import Applied
from elphel_host.errors import UnsupportedError

__all__ = [
    "Applied",
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
