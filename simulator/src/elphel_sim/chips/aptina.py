"""What the simulated Aptina sensors (MT9P006, MT9F002) share.

A latched register file built from the daemon's table, whose colour gains are written
together by ``global_gain``; when a write reaches the image (two frames for the
registers a model names, one for colour gains); and the image: a Bayer readout decoded
from the registers in effect, flips and trigger mode read through the table's fields, the
gain codes through the driver's gain code. Each model supplies its window, row time and
exposure from its registers.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Mapping
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from elphel_camd.sensors.registers import RegisterTable
from elphel_sim.chips.registers import SimLatchedChip
from elphel_sim.chips.sensor import ImageContext, SensorTiming, SimSensor
from elphel_sim.fpga import FrameRecord
from elphel_sim.render import Readout, blurred_strips, read_out

# The colour-gain registers (same names on both sensors), in the order of their addresses.
COLOUR_GAINS = ("green1_gain", "blue_gain", "red_gain", "green2_gain")


class SimAptinaChip(SimLatchedChip, SimSensor):
    """An Aptina Bayer sensor's register file, latencies, timing and readout."""

    register_table: ClassVar[RegisterTable]
    address_step: ClassVar[int]  # address increment between consecutive registers
    bayer: ClassVar[str]
    # Registers whose writes reach the image two frames later (colour gains: one).
    two_frames: ClassVar[tuple[str, ...]]
    # The fields of the horizontal and vertical flip and of the trigger (snapshot) mode.
    fliph_field: ClassVar[str]
    flipv_field: ClassVar[str]
    snapshot_field: ClassVar[str]

    def __init__(self) -> None:
        super().__init__(self.register_table, step=self.address_step, colour_gains=COLOUR_GAINS)
        self._latency = {self.table[name].address: 2 for name in self.two_frames}
        self._latency.update({self.table[name].address: 1 for name in COLOUR_GAINS})

    @staticmethod
    @abstractmethod
    def decode_gain(code: int) -> float:
        """Total gain of a colour-gain register code (the driver's gain code)."""

    @staticmethod
    @abstractmethod
    def window_of(registers: Mapping[str, int]) -> tuple[int, int, int, int]:
        """Left, top, width and height of the readout in array pixels."""

    @staticmethod
    @abstractmethod
    def row_s_of(registers: Mapping[str, int]) -> float:
        """Row duration from the registers in effect."""

    @staticmethod
    @abstractmethod
    def exposure_rows_of(registers: Mapping[str, int]) -> int:
        """Integration in rows, as the sensor applies it."""

    @staticmethod
    @abstractmethod
    def frame_rows_of(registers: Mapping[str, int]) -> int:
        """Rows of a free-running frame, blanking and a long exposure included."""

    # -- what the FPGA needs -----------------------------------------------------------------

    def timing(self) -> SensorTiming:
        """Row time, rows per frame and exposure rows from the registers in effect."""
        regs = self.image_registers()
        return SensorTiming(
            row_s=self.row_s_of(regs),
            frame_rows=self.frame_rows_of(regs),
            exposure_rows=self.exposure_rows_of(regs),
            height=self.window_of(regs)[3],
        )

    def is_snapshot(self) -> bool:
        return bool(self.image_field(self.snapshot_field))

    def render(self, record: FrameRecord, context: ImageContext) -> NDArray[np.uint16]:
        r: Mapping[str, int] = record.registers
        left, top, width, height = self.window_of(r)
        fliph, flipv = (self.table.field(name) for name in (self.fliph_field, self.flipv_field))
        readout = Readout(
            left=left,
            top=top,
            width=width,
            height=height,
            exposure_us=self.exposure_rows_of(r) * self.row_s_of(r) * 1e6,
            gains=(
                self.decode_gain(r["red_gain"]),
                self.decode_gain(r["green1_gain"]),
                self.decode_gain(r["green2_gain"]),
                self.decode_gain(r["blue_gain"]),
            ),
            fliph=bool(fliph.get(r[fliph.register.name])),
            flipv=bool(flipv.get(r[flipv.register.name])),
            bayer=self.bayer,
        )
        intrinsics = context.intrinsics
        if context.calib is not None:  # the calibration board through the port's own lens
            board = context.calib.radiance(record.board, readout.window_on(intrinsics))
            rgb = np.repeat(board, len(record.strip_times_s()), axis=0)
            return read_out(rgb, readout, model=context.model, rng=context.rng)
        # A still scene seen again from the same pose and window reuses its radiance (the
        # renderer's cache); the lens blur, exposure, gains, flips and this frame's noise
        # are applied here.
        rgb = blurred_strips(
            context.world,
            intrinsics,
            record.pose,
            window=readout.window_on(intrinsics),
            times_s=record.strip_times_s(),
            blur=context.lens_blur,
        )
        return read_out(rgb, readout, model=context.model, rng=context.rng)
