"""Video over SPI from a FLIR Lepton 3.x: packets, segments, whole frames, byte sources.

`VoSPIReader` reads whole frames from a `ByteSource` (`open_source`: a spidev node, or a
file or FIFO carrying the same bytes); `packets` owns the wire format, `segments` the
assembly of frames, `telemetry` the telemetry rows.
"""

from elphel_camd.vospi.errors import (
    NotVoSPIError,
    VoSPIError,
    VoSPISetupError,
    VoSPITimeoutError,
)
from elphel_camd.vospi.reader import VoSPIFrame, VoSPIReader
from elphel_camd.vospi.sources import (
    ByteSource,
    FileSource,
    LinuxSpidev,
    SpiDevice,
    SpidevSource,
    open_source,
)
from elphel_camd.vospi.telemetry import Telemetry

__all__ = [
    "ByteSource",
    "FileSource",
    "LinuxSpidev",
    "NotVoSPIError",
    "SpiDevice",
    "SpidevSource",
    "Telemetry",
    "VoSPIError",
    "VoSPIFrame",
    "VoSPIReader",
    "VoSPISetupError",
    "VoSPITimeoutError",
    "open_source",
]
