"""REST client for elphel-camd."""

from elphel_host.camera.client import (
    Applied,
    Burst,
    Camera,
    CameraClient,
    CameraEvent,
    CameraHTTPError,
    CameraUnauthorizedError,
    CapturedFrame,
    PhotoFinish,
)

__all__ = [
    "Applied",
    "Burst",
    "Camera",
    "CameraClient",
    "CameraEvent",
    "CameraHTTPError",
    "CameraUnauthorizedError",
    "CapturedFrame",
    "PhotoFinish",
]
