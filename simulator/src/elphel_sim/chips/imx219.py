"""Simulated Sony IMX219: byte registers at 16-bit addresses, latencies, RAW10 readout.

The register file comes from the daemon's table (`elphel_camd.sensors.imx219`). On the
wire the chip is byte-addressed: a write carries a 16-bit register address and then any
number of bytes to consecutive addresses; a read returns bytes from the last addressed
byte on. A 16-bit register is its two bytes, high byte first. Bytes no register declares
are kept and read back as written (0 until then); the chip id is read-only.

Timing (as the driver's ahead table): a write to the exposure, the frame or line length,
the crop, the output size, the orientation or the binning made during frame F shapes the
image of frame F + 2; the gains reach frame F + 1; the mode select acts at once. A chip
in software standby starts no frame.

Image: the crop of the active area (origin (8, 8) of the 3296 x 2480 array) through the
RGGB filter, the exposure in lines of ``line_length_pck`` pixel clocks at 182.4 MHz, one
gain for all colours (analogue code and digital value), the flips, 2x2 binning of each
colour (both binning modes average the four same-colour pixels here), and the output
size (the readout cut to ``x_output_size`` x ``y_output_size``), in 10 bits.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from elphel_camd.sensors import imx219 as spec
from elphel_camd.sensors import imx219_registers as regs
from elphel_camd.sensors.imx219_registers import byte_addresses, register_bytes
from elphel_camd.sensors.registers import Access, Register
from elphel_sim.chips.registers import SimLatchedChip
from elphel_sim.chips.sensor import ImageContext, SensorTiming, SimSensor
from elphel_sim.fpga import FrameRecord
from elphel_sim.render import Readout, blurred_strips, read_out

_STREAMING = regs.TABLE.field("mode_select.streaming")
_HFLIP = regs.TABLE.field("orientation.hflip")
_VFLIP = regs.TABLE.field("orientation.vflip")
_TWO_FRAMES = (
    "coarse_integration_time",
    "frame_length_lines",
    "line_length_pck",
    "x_addr_start",
    "x_addr_end",
    "y_addr_start",
    "y_addr_end",
    "x_output_size",
    "y_output_size",
    "orientation",
    "binning_mode_h",
    "binning_mode_v",
)
_ONE_FRAME = ("analogue_gain", "digital_gain")


def row_s_of(registers: Mapping[str, int]) -> float:
    """Line duration from the registers in effect."""
    return spec.row_time_s(line_length_pixels=registers["line_length_pck"])


def exposure_lines_of(registers: Mapping[str, int]) -> int:
    """Integration as the sensor applies it: at most the frame length minus 4 lines."""
    frame = registers["frame_length_lines"] - spec.EXPOSURE_MARGIN_LINES
    return max(0, min(registers["coarse_integration_time"], frame))


def crop_of(registers: Mapping[str, int]) -> tuple[int, int, int, int]:
    """Left, top, width and height of the crop in array pixels."""
    r = registers
    width = max(0, r["x_addr_end"] - r["x_addr_start"] + 1)
    height = max(0, r["y_addr_end"] - r["y_addr_start"] + 1)
    return regs.ACTIVE_LEFT + r["x_addr_start"], regs.ACTIVE_TOP + r["y_addr_start"], width, height


def bin_bayer(image: NDArray[np.uint16], *, horizontal: bool, vertical: bool) -> NDArray[np.uint16]:
    """Average each colour's 2 neighbours of the same colour along the binned axes.

    A Bayer image stays a Bayer image of the same order at half the size along each
    binned axis (an odd 2x2 cell left over at the edge is dropped).
    """
    out = image.astype(np.float32)
    if vertical:
        h = out.shape[0] // 4 * 4
        out = out[:h].reshape(h // 4, 2, 2, -1).mean(axis=1).reshape(h // 2, -1)
    if horizontal:
        w = out.shape[1] // 4 * 4
        out = out[:, :w].reshape(out.shape[0], w // 4, 2, 2).mean(axis=2).reshape(-1, w // 2)
    binned: NDArray[np.uint16] = np.rint(out).astype(np.uint16)
    return binned


class SimIMX219(SimLatchedChip, SimSensor):
    """IMX219 at I2C address 0x10: byte registers, latencies and RAW10 readout."""

    address = regs.I2C_ADDRESS
    model = regs.MODEL

    def __init__(self) -> None:
        super().__init__(regs.TABLE, step=1)
        self._bytes: dict[int, tuple[Register, int]] = {
            address: (r, i) for address, r, i in byte_addresses(regs.TABLE)
        }
        self._loose: dict[int, int] = {}  # bytes no register declares
        self._latency = {regs.TABLE[name].address: 2 for name in _TWO_FRAMES}
        self._latency.update({regs.TABLE[name].address: 1 for name in _ONE_FRAME})

    def latency(self, address: int) -> int:
        return self._latency.get(address, 0)

    # -- bytes on the wire -------------------------------------------------------------------

    def _write_byte(self, address: int, byte: int) -> None:
        found = self._bytes.get(address)
        if found is None:
            self._loose[address] = byte
            return
        register, index = found
        shift = 8 * (register_bytes(register) - 1 - index)
        old = self.values.get(register.address, register.reset)
        value = (old & ~(0xFF << shift)) | byte << shift
        self.write_log.append((register.address, value))
        self.on_register_write(register.address, value)

    def _read_byte(self, address: int) -> int:
        found = self._bytes.get(address)
        if found is None:
            return self._loose.get(address, 0)
        register, index = found
        if register.access is Access.WO:
            return 0
        shift = 8 * (register_bytes(register) - 1 - index)
        return (self.values[register.address] >> shift) & 0xFF

    def on_write(self, data: bytes) -> None:
        if len(data) < 2:
            return
        self._pointer = int.from_bytes(data[:2], "big")
        for byte in data[2:]:
            self._write_byte(self._pointer, byte)
            self._pointer += 1

    def on_read(self, length: int) -> bytes:
        out = bytearray()
        for _ in range(length):
            out.append(self._read_byte(self._pointer))
            self._pointer += 1
        return bytes(out)

    # -- what the FPGA needs -----------------------------------------------------------------

    def timing(self) -> SensorTiming:
        r = self.image_registers()
        exposure = exposure_lines_of(r)
        return SensorTiming(
            row_s=row_s_of(r),
            frame_rows=max(r["frame_length_lines"], exposure + spec.EXPOSURE_MARGIN_LINES),
            exposure_rows=exposure,
            height=r["y_output_size"],
        )

    def is_snapshot(self) -> bool:
        """A chip in software standby waits: it starts no frame until it streams."""
        return not self.image_field(_STREAMING.name)

    def render(self, record: FrameRecord, context: ImageContext) -> NDArray[np.uint16]:
        r: Mapping[str, int] = record.registers
        left, top, width, height = crop_of(r)
        gain = spec.total_gain(r["analogue_gain"], r["digital_gain"])
        readout = Readout(
            left=left,
            top=top,
            width=width,
            height=height,
            exposure_us=exposure_lines_of(r) * row_s_of(r) * 1e6,
            gains=(gain, gain, gain, gain),
            fliph=bool(_HFLIP.get(r["orientation"])),
            flipv=bool(_VFLIP.get(r["orientation"])),
            bayer=regs.BAYER,
        )
        rgb = blurred_strips(
            context.world,
            context.intrinsics,
            record.pose,
            window=readout.window_on(context.intrinsics),
            times_s=record.strip_times_s(),
            blur=context.lens_blur,
        )
        image = read_out(rgb, readout, model=context.model, rng=context.rng)
        horizontal, vertical = bool(r["binning_mode_h"]), bool(r["binning_mode_v"])
        if horizontal or vertical:
            image = bin_bayer(image, horizontal=horizontal, vertical=vertical)
        return np.ascontiguousarray(image[: r["y_output_size"], : r["x_output_size"]])
