"""Simulated MT9F002: register file, gain aliasing, and when a write reaches the image.

The register file and its fields come from the daemon's table (16-bit addresses,
consecutive 16-bit registers two addresses apart).

Timing (Elphel's MT9F002 driver: its exposure model and its table of frames ahead): a
write to the window, the read mode (flips), the exposure or the frame/line length made
during frame F shapes the image of frame F + 2 in both free-run and snapshot mode
(Elphel's MT9F002 needs 2 frames ahead in async mode too); colour gains reach frame
F + 1; the slave mode reaches frame F + 2 in free-run and F + 1 once triggered. Other
registers act at once. The exposure is clamped to one row less than the frame, as an
SMIA sensor clamps coarse integration to its frame length.
"""

from __future__ import annotations

from collections.abc import Mapping

from elphel_camd.sensors import mt9f002 as spec
from elphel_sim.chips.aptina import SimAptinaChip

_FLIPH = spec.TABLE.field("read_mode.flip_horizontal")
_FLIPV = spec.TABLE.field("read_mode.flip_vertical")
_ORDER_COLUMN = spec.TABLE.field("pixel_order.column")
_ORDER_ROW = spec.TABLE.field("pixel_order.row")


def row_s_of(registers: Mapping[str, int]) -> float:
    """Row duration from the registers in effect (Elphel's model, as the driver's)."""
    width = registers["x_output_size"]
    return spec.row_clocks(width, registers["line_length_pck"]) / spec.VT_PIX_CLK_HZ


def exposure_rows_of(registers: Mapping[str, int]) -> int:
    """Coarse integration as the sensor applies it: at most one row less than the frame."""
    return max(0, min(registers["coarse_integration_time"], registers["frame_length_lines"] - 1))


class SimMT9F002(SimAptinaChip):
    """MT9F002 at I2C address 0x10 with 16-bit register addresses."""

    address = spec.I2C_ADDRESS
    model = spec.MODEL
    register_table = spec.TABLE
    address_step = 2
    bayer = spec.BAYER  # the array's cell at even coordinates is pixel_order 0
    decode_gain = staticmethod(spec.decode_gain)
    two_frames = (
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
    fliph_field = _FLIPH.name
    flipv_field = _FLIPV.name
    snapshot_field = "slave_mode.triggered"

    def latency(self, address: int) -> int:
        if address == self.table["slave_mode"].address:
            return 1 if self.is_snapshot() else 2
        return self._latency.get(address, 0)

    def latch(self, frame: int) -> None:
        super().latch(frame)
        # pixel_order reports the colour of the first pixel read: an odd start or a flip
        # (of an even-sized window) moves it by one column or row.
        column = (self.image_field(_FLIPH.name) ^ self.image_register("x_addr_start")) & 1
        row = (self.image_field(_FLIPV.name) ^ self.image_register("y_addr_start")) & 1
        order = _ORDER_ROW.put(_ORDER_COLUMN.put(0, column), row)
        address = _ORDER_COLUMN.register.address
        self.effective[address] = self.values[address] = order

    @staticmethod
    def window_of(registers: Mapping[str, int]) -> tuple[int, int, int, int]:
        r = registers
        return r["x_addr_start"], r["y_addr_start"], r["x_output_size"], r["y_output_size"]

    row_s_of = staticmethod(row_s_of)
    exposure_rows_of = staticmethod(exposure_rows_of)

    @staticmethod
    def frame_rows_of(registers: Mapping[str, int]) -> int:
        return registers["frame_length_lines"]
