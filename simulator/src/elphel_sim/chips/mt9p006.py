"""Simulated MT9P006: register file, aliases, and when a write reaches the image.

The register file and its fields come from the daemon's table.

Timing (the MT9P031/MT9P006 datasheet's "maintaining a constant frame rate"): in
free-run, a write to the shutter width, the window, blanking or read modes made during
frame F shapes the image of frame F + 2 (window changes cost a bubble frame); colour
gains reach frame F + 1. In snapshot mode every frame-synchronised register reaches the
next triggered frame. Registers outside these groups (reset, restart, test pattern, ...)
act at once.
"""

from __future__ import annotations

from collections.abc import Mapping

from elphel_camd.sensors import mt9p006 as spec
from elphel_sim.chips.aptina import SimAptinaChip

_SOFT_RESET = spec.TABLE.field("reset.soft_reset")
_RESTART = spec.TABLE.field("restart.restart")


def _shutter_rows(r: Mapping[str, int]) -> int:
    return (r["shutter_width_upper"] << 16) | r["shutter_width_lower"]


class SimMT9P006(SimAptinaChip):
    """MT9P006 at I2C address 0x48 with 8-bit register addresses."""

    address = spec.I2C_ADDRESS
    model = spec.MODEL
    register_table = spec.TABLE
    address_step = 1
    bayer = spec.BAYER
    decode_gain = staticmethod(spec.decode_gain)
    two_frames = (
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
    fliph_field = "read_mode_2.mirror_column"
    flipv_field = "read_mode_2.mirror_row"
    snapshot_field = "read_mode_1.snapshot"

    def latency(self, address: int) -> int:
        frames = self._latency.get(address, 0)
        return min(frames, 1) if self.is_snapshot() else frames

    def on_register_write(self, address: int, value: int) -> None:
        if address == _SOFT_RESET.register.address and _SOFT_RESET.get(value):
            self.reset()
        elif address == _RESTART.register.address:
            self.values[address] = _RESTART.put(value, 0)  # restart is self-clearing
        else:
            super().on_register_write(address, value)

    @staticmethod
    def window_of(registers: Mapping[str, int]) -> tuple[int, int, int, int]:
        r = registers
        return r["column_start"], r["row_start"], r["column_size"] + 1, r["row_size"] + 1

    @staticmethod
    def row_s_of(registers: Mapping[str, int]) -> float:
        width = registers["column_size"] + 1
        return spec.row_time_s(width, horizontal_blank=registers["horizontal_blank"])

    @staticmethod
    def exposure_rows_of(registers: Mapping[str, int]) -> int:
        return _shutter_rows(registers)

    @staticmethod
    def frame_rows_of(registers: Mapping[str, int]) -> int:
        height = registers["row_size"] + 1
        return max(height + registers["vertical_blank"], _shutter_rows(registers) + 1)
