"""Errors of the VoSPI frame path: each names the device (or file) and what to do."""

from __future__ import annotations

from elphel_camd.errors import CameraError


class VoSPIError(CameraError, OSError):
    """The VoSPI device or file cannot be used (missing, refused, misconfigured)."""


class VoSPISetupError(VoSPIError, ValueError):
    """The spidev setup does not fit the Lepton (SPI mode, clock, spidev bufsiz)."""


class NotVoSPIError(VoSPIError, ValueError):
    """The byte stream holds no VoSPI packets (no packet's CRC matched)."""


class VoSPITimeoutError(CameraError, TimeoutError):
    """No frame came from the Lepton in time (the device stopped sending)."""
