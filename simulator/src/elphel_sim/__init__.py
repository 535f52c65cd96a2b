"""elphel-sim: a software model of the rig (sensor chips, camera board, stage, scene)."""

__version__ = "0.1.0"
