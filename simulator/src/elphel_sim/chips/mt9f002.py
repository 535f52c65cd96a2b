"""Simulated MT9F002: register file, gain aliasing, and when a write reaches the image.

The register file comes from the daemon's table (16-bit addresses, consecutive 16-bit
registers two addresses apart).

Timing (reference sections 2.4 and 3.3): a write to the window, the read mode (flips),
the exposure or the frame/line length made during frame F shapes the image of frame F + 2
in both free-run and snapshot mode (Elphel's MT9F002 needs 2 frames ahead in async mode
too); colour gains reach frame F + 1; the slave mode reaches frame F + 2 in free-run and
F + 1 once triggered. Other registers act at once. The exposure is clamped to one row less
than the frame, as an SMIA sensor clamps coarse integration to its frame length.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from elphel_camd.sensors import mt9f002 as spec
from elphel_sim.chips.registers import SimLatchedChip
from elphel_sim.chips.sensor import SensorTiming
from elphel_sim.fpga import FrameRecord
from elphel_sim.render import Intrinsics, Readout, SensorModel, read_out, render_strips
from elphel_sim.world import World

_COLOUR_GAINS = ("green1_gain", "blue_gain", "red_gain", "green2_gain")
_TWO_FRAMES = (
    "x_addr_start",
    "x_addr_end",
    "y_addr_start",
    "y_addr_end",
    "x_output_size",
    "y_output_size",
    "read_mode",
    "coarse_integration_time",
    "frame_length_lines",
    "line_length_pck",
)
SLAVE_TRIGGERED_BIT = 0x8000  # slave_mode: 0xA000 triggered, 0x2000 free-run


def row_s_of(registers: Mapping[str, int]) -> float:
    """Row duration from the registers in effect (Elphel's model, as the driver's)."""
    width = registers["x_output_size"]
    return spec.row_clocks(width, registers["line_length_pck"]) / spec.VT_PIX_CLK_HZ


def exposure_rows_of(registers: Mapping[str, int]) -> int:
    """Coarse integration as the sensor applies it: at most one row less than the frame."""
    return max(0, min(registers["coarse_integration_time"], registers["frame_length_lines"] - 1))


class SimMT9F002(SimLatchedChip):
    """MT9F002 at I2C address 0x10 with 16-bit register addresses."""

    address = spec.I2C_ADDRESS
    model = spec.MODEL

    def __init__(self) -> None:
        super().__init__(spec.TABLE, step=2, colour_gains=_COLOUR_GAINS)
        self._latency = {spec.TABLE[name].address: 2 for name in _TWO_FRAMES}
        self._latency.update({spec.TABLE[name].address: 1 for name in _COLOUR_GAINS})
        self._slave_mode = spec.TABLE["slave_mode"].address

    def latency(self, address: int) -> int:
        if address == self._slave_mode:
            return 1 if self.is_snapshot() else 2
        return self._latency.get(address, 0)

    def latch(self, frame: int) -> None:
        super().latch(frame)
        # pixel_order reports the colour of the first pixel read: an odd start or a flip
        # (of an even-sized window) moves it by one column or row.
        r = self.image_register
        order = ((r("read_mode") >> 14 ^ r("x_addr_start")) & 1) | (
            (r("read_mode") >> 15 ^ r("y_addr_start")) & 1
        ) << 1
        pixel_order = self.table["pixel_order"].address
        self.effective[pixel_order] = self.values[pixel_order] = order

    # -- what the FPGA needs -----------------------------------------------------------------

    def timing(self) -> SensorTiming:
        """Row time, rows per frame and exposure rows from the registers in effect."""
        regs = self.image_registers()
        return SensorTiming(
            row_s=row_s_of(regs),
            frame_rows=regs["frame_length_lines"],
            exposure_rows=exposure_rows_of(regs),
            height=regs["y_output_size"],
        )

    def is_snapshot(self) -> bool:
        return bool(self.image_register("slave_mode") & SLAVE_TRIGGERED_BIT)

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
        read_mode = r["read_mode"]
        fliph, flipv = (
            bool(read_mode & spec.READ_MODE_FLIPH),
            bool(read_mode & spec.READ_MODE_FLIPV),
        )
        left, top = r["x_addr_start"], r["y_addr_start"]
        readout = Readout(
            left=left,
            top=top,
            width=r["x_output_size"],
            height=r["y_output_size"],
            exposure_us=exposure_rows_of(r) * row_s_of(r) * 1e6,
            gains=(
                spec.decode_gain(r["red_gain"]),
                spec.decode_gain(r["green1_gain"]),
                spec.decode_gain(r["green2_gain"]),
                spec.decode_gain(r["blue_gain"]),
            ),
            fliph=fliph,
            flipv=flipv,
            bayer=spec.BAYER,  # the array's cell at even coordinates is pixel_order 0
        )
        window, times = readout.window_on(intrinsics), record.strip_times_s()
        rgb = render_strips(world, intrinsics, record.pose, window=window, times_s=times)
        return read_out(rgb, readout, model=model, rng=rng)
