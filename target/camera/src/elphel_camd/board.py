"""Deprecated: the old home of the boards and the camera service.

The Board protocol, `Frame` and the I2C board are in `elphel_camd.boards`, the camera
service is `elphel_camd.service.CameraService` (``Camera`` here) and `bayer_after_flips`
is in `elphel_camd.frame_metadata`. Importing a name from here still works and warns.
"""

from __future__ import annotations

from elphel_camd.deprecation import moved

__getattr__ = moved(
    __name__,
    {
        "Board": "elphel_camd.boards:Board",
        "BoardFactory": "elphel_camd.boards:BoardFactory",
        "Frame": "elphel_camd.boards:Frame",
        "FrameSync": "elphel_camd.boards:FrameSync",
        "I2CBoard": "elphel_camd.boards:I2CBoard",
        "board_factories": "elphel_camd.boards:board_factories",
        "Camera": "elphel_camd.service:CameraService",
        "bayer_after_flips": "elphel_camd.frame_metadata:bayer_after_flips",
    },
)
