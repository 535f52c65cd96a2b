"""The camera board's image path: forms each frame from the sensor's register state.

A frame is rendered from the world as the registers of the chip say it was taken: window
origin and size, exposure (shutter rows x row time), per-colour analog gains, mirroring
and the Bayer phase that follows from them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from elphel_camd.sensors import mt9p006 as spec
from elphel_sim.chips.mt9p006 import SimMT9P006
from elphel_sim.render import Intrinsics, SensorModel, bayer_channels, expose, render_radiance
from elphel_sim.world import World


@dataclass(frozen=True)
class SensorTiming:
    """Frame timing implied by a window, as the MT9P006 runs it at the sensor clock."""

    width: int
    height: int
    vertical_blank: int

    @property
    def row_s(self) -> float:
        return spec.row_time_s(self.width)

    @property
    def frame_s(self) -> float:
        return self.row_s * (self.height + max(self.vertical_blank, 9))


def mt9p006_frame(
    chip: SimMT9P006,
    world: World,
    *,
    intrinsics: Intrinsics,
    mount: str,
    model: SensorModel,
    rng: np.random.Generator | None,
    time_s: float,
) -> NDArray[np.uint16]:
    """Render one MT9P006 frame from the chip's registers and the world at ``time_s``.

    The ``intrinsics`` describe the full pixel array (``spec.ARRAY_WIDTH`` x
    ``spec.ARRAY_HEIGHT``), so register window coordinates address it directly.
    """
    left = chip.peek("column_start")
    top = chip.peek("row_start")
    width = chip.peek("column_size") + 1
    height = chip.peek("row_size") + 1
    width = min(width, intrinsics.width - left)
    height = min(height, intrinsics.height - top)
    shutter_rows = (chip.peek("shutter_width_upper") << 16) | chip.peek("shutter_width_lower")
    exposure_us = shutter_rows * spec.row_time_s(width) * 1e6
    read_mode_2 = chip.peek("read_mode_2")
    fliph, flipv = bool(read_mode_2 >> 14 & 1), bool(read_mode_2 >> 15 & 1)

    pose = world.camera_pose(mount)
    rgb = render_radiance(world, intrinsics, pose, window=(left, top, width, height), time_s=time_s)
    channels = bayer_channels(spec.BAYER, (height, width), row0=top, col0=left)
    radiance = np.take_along_axis(rgb, channels[..., None], axis=2)[..., 0]
    gains = np.array(
        [spec.decode_gain(chip.peek(name)) for name in ("red_gain", "green1_gain", "blue_gain")]
    )
    gain = gains[channels]
    # The second green sits on the rows of blue.
    rows_with_blue = (channels == 2).any(axis=1)
    green2 = (channels == 1) & rows_with_blue[:, None]
    gain[green2] = spec.decode_gain(chip.peek("green2_gain"))
    image = expose(radiance, exposure_us=exposure_us, gain=gain, model=model, rng=rng)
    if fliph:
        image = image[:, ::-1]
    if flipv:
        image = image[::-1, :]
    return np.ascontiguousarray(image)
