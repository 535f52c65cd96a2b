"""elphel-camd: sensor control and REST API for Elphel-style multi-sensor camera boards."""

__version__ = "0.1.0"
