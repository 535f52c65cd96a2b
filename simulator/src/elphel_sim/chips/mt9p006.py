"""Simulated MT9P006: register file, aliases, and when a write reaches the image.

The register file comes from the daemon's table.

Timing (datasheet facts, reference sections 1.2 and 1.4): in free-run, a write to the
shutter width, the window, blanking or read modes made during frame F shapes the image of
frame F + 2 (window changes cost a bubble frame); colour gains reach frame F + 1. In
snapshot mode every frame-synchronised register reaches the next triggered frame.
Registers outside these groups (reset, restart, test pattern, ...) act at once.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from elphel_camd.sensors import mt9p006 as spec
from elphel_sim.chips.registers import SimLatchedChip
from elphel_sim.chips.sensor import SensorTiming
from elphel_sim.fpga import FrameRecord
from elphel_sim.render import Intrinsics, Readout, SensorModel, read_out, render_strips
from elphel_sim.world import World

_COLOUR_GAINS = ("green1_gain", "blue_gain", "red_gain", "green2_gain")
_TWO_FRAMES = (
    "shutter_width_upper",
    "shutter_width_lower",
    "row_start",
    "column_start",
    "row_size",
    "column_size",
    "horizontal_blank",
    "vertical_blank",
    "read_mode_1",
    "read_mode_2",
    "row_address_mode",
    "column_address_mode",
)
SNAPSHOT_BIT = 0x0100  # read_mode_1 bit 8


class SimMT9P006(SimLatchedChip):
    """MT9P006 at I2C address 0x48 with 8-bit register addresses."""

    address = spec.I2C_ADDRESS
    model = spec.MODEL

    def __init__(self) -> None:
        super().__init__(spec.TABLE, step=1, colour_gains=_COLOUR_GAINS)
        self._latency = {spec.TABLE[name].address: 2 for name in _TWO_FRAMES}
        self._latency.update({spec.TABLE[name].address: 1 for name in _COLOUR_GAINS})

    def latency(self, address: int) -> int:
        frames = self._latency.get(address, 0)
        snapshot = self.effective[spec.TABLE["read_mode_1"].address] & SNAPSHOT_BIT
        return min(frames, 1) if snapshot else frames

    def on_register_write(self, address: int, value: int) -> None:
        table = self.table
        if address == table["reset"].address and value & 1:
            self.reset()
        elif address == table["restart"].address:
            self.values[address] = value & ~1  # restart is self-clearing
        else:
            super().on_register_write(address, value)

    # -- what the FPGA needs -----------------------------------------------------------------

    def timing(self) -> SensorTiming:
        """Row time, rows per frame and exposure rows from the registers in effect."""
        r = self.image_register
        width = r("column_size") + 1
        row_s = (width + 2 * r("horizontal_blank")) / spec.SENSOR_CLOCK_HZ
        height = r("row_size") + 1
        shutter = (r("shutter_width_upper") << 16) | r("shutter_width_lower")
        rows = max(height + r("vertical_blank"), shutter + 1)
        return SensorTiming(row_s=row_s, frame_rows=rows, exposure_rows=shutter, height=height)

    def is_snapshot(self) -> bool:
        return bool(self.image_register("read_mode_1") & SNAPSHOT_BIT)

    @staticmethod
    def form_image(
        record: FrameRecord,
        world: World,
        *,
        intrinsics: Intrinsics,
        model: SensorModel,
        rng: np.random.Generator | None,
    ) -> NDArray[np.uint16]:
        r: Mapping[str, int] = record.registers
        width = r["column_size"] + 1
        row_s = (width + 2 * r["horizontal_blank"]) / spec.SENSOR_CLOCK_HZ
        shutter = (r["shutter_width_upper"] << 16) | r["shutter_width_lower"]
        readout = Readout(
            left=r["column_start"],
            top=r["row_start"],
            width=width,
            height=r["row_size"] + 1,
            exposure_us=shutter * row_s * 1e6,
            gains=(
                spec.decode_gain(r["red_gain"]),
                spec.decode_gain(r["green1_gain"]),
                spec.decode_gain(r["green2_gain"]),
                spec.decode_gain(r["blue_gain"]),
            ),
            fliph=bool(r["read_mode_2"] >> 14 & 1),
            flipv=bool(r["read_mode_2"] >> 15 & 1),
            bayer=spec.BAYER,
        )
        window, times = readout.window_on(intrinsics), record.strip_times_s()
        rgb = render_strips(world, intrinsics, record.pose, window=window, times_s=times)
        return read_out(rgb, readout, model=model, rng=rng)
