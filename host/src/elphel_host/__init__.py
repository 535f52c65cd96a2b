"""elphel-host: camera and stage clients, bursts, MFSR and the tile processor."""

__version__ = "0.1.0"
