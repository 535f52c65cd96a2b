"""REST client for elphel-camd."""

from elphel_host.camera.client import CameraClient, CapturedFrame

__all__ = ["CameraClient", "CapturedFrame"]
