"""REST client for elphel-camd."""

from __future__ import annotations

import warnings
from typing import Any

from elphel_host.camera.client import (
    Applied,
    CameraClient,
    CameraHTTPError,
    CameraUnauthorizedError,
)
from elphel_host.camera.events import CameraEvent
from elphel_host.camera.frames import Burst, CapturedBurst, CapturedFrame, PhotoFinish

__all__ = [
    "Applied",
    "Burst",
    "CameraClient",
    "CameraEvent",
    "CameraHTTPError",
    "CameraUnauthorizedError",
    "CapturedBurst",
    "CapturedFrame",
    "PhotoFinish",
]


def __getattr__(name: str) -> Any:
    # `Camera` was the client's name before 0.2; scripts that import it keep working.
    if name == "Camera":
        warnings.warn(
            "elphel_host.camera.Camera is now CameraClient", DeprecationWarning, stacklevel=2
        )
        return CameraClient
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
