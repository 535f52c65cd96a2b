"""Simulated FLIR Lepton 3.5: the CCI state machine and a TLinear thermal image.

The register file comes from the daemon's table of the CCI registers. Writing the command
register runs the command (reference 5.1): the status register then reads BUSY for a
number of polls (``sim_busy_polls``, more for an FFC), and its error field (bits 15:8)
carries the result: 0, or a FLIR SDK error code for an unknown command or a missing
protection bit (-7, undefined function), a data length that does not match the attribute
(-6, data size) or an enum out of range (-3, range). GET results are in the data
registers. Boot bits read 1 once booted (``sim_reboot`` makes the camera boot again over
some polls).

Image: the scene's radiance seen through the Lepton's optics (the port's intrinsics),
mapped linearly to scene temperature, 283.15 K at radiance 0 to 303.15 K at radiance 1,
with 50 mK temporal noise when the board renders noise. TLinear on (radiometry on) gives
kelvin in 0.01 K or 0.1 K counts; TLinear off gives 14-bit flux counts, 8192 at the FPA
temperature and 30 counts per kelvin. With telemetry on, two rows (footer or header)
carry the telemetry the daemon decodes (`elphel_camd.vospi.telemetry`): revision, uptime,
FFC state, frame counter, frame mean, FPA temperature, TLinear state and resolution; the
rest 0.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from elphel_camd.sensors import cci
from elphel_camd.sensors import lepton35 as spec
from elphel_sim.chips.registers import SimRegisterChip
from elphel_sim.chips.sensor import ImageContext, SensorTiming, SimSensor
from elphel_sim.fpga import FrameRecord
from elphel_sim.render import Intrinsics, render_radiance
from elphel_sim.vospi import telemetry_rows

ERROR_RANGE = -3
ERROR_DATA_SIZE = -6
ERROR_UNDEFINED = -7

SCENE_MIN_K = 283.15  # radiance 0
SCENE_SPAN_K = 20.0  # radiance 1 is 303.15 K
NETD_K = 0.05
RAW_AT_FPA = 8192
RAW_PER_K = 30.0
FFC_NEVER = 0  # telemetry FFC state: never commanded
FFC_DONE = 3  # complete
_ERROR = cci.REGISTERS.field("status.error")

# Enum attributes: power-on value (reference 5.2) and the values a SET accepts.
_ENUMS: dict[str, tuple[int, range]] = {
    "AGC_ENABLE": (0, range(2)),
    "SYS_TELEMETRY_ENABLE": (0, range(2)),
    "SYS_TELEMETRY_LOCATION": (1, range(2)),
    "OEM_GPIO_MODE": (0, range(6)),
    "RAD_ENABLE": (1, range(2)),
    "RAD_TLINEAR_ENABLE": (1, range(2)),
    "RAD_TLINEAR_RESOLUTION": (1, range(2)),
}


def lepton_intrinsics() -> Intrinsics:
    """160 x 120 at 12 µm behind a 1.8 mm lens: about 56 degrees across."""
    return Intrinsics(
        focal_length_mm=1.8,
        pixel_pitch_um=spec.PIXEL_PITCH_UM,
        width=spec.WIDTH,
        height=spec.HEIGHT,
    )


class SimLepton35(SimRegisterChip, SimSensor):
    """Lepton 3.5 at I2C address 0x2A: CCI registers, commands, frames at 8.7 fps."""

    address = spec.I2C_ADDRESS
    model = spec.MODEL

    def __init__(self) -> None:
        super().__init__(cci.REGISTERS, step=2)
        self.sim_busy_polls = 2
        self.sim_ffc_polls = 6
        self.sim_fpa_temperature_k = 305.15
        self.attributes: dict[str, int] = {name: v for name, (v, _) in _ENUMS.items()}
        self.ffc_count = 0
        self.last_ffc_frame = 0
        self.commands_run: list[int] = []
        self.frame = 0
        self._busy = 0
        self._booting = 0
        self._error = 0
        self._by_base = {c.base: c for c in cci.COMMANDS.values()}

    # -- fault and state hooks -------------------------------------------------------------

    def sim_reboot(self, polls: int = 3) -> None:
        """Start booting: the boot bits read 0 (and BUSY 1) for ``polls`` status reads."""
        self._booting = polls
        self.attributes = {name: v for name, (v, _) in _ENUMS.items()}

    # -- CCI -------------------------------------------------------------------------------

    def _status(self) -> int:
        if self._booting:
            return cci.STATUS_BUSY
        busy = cci.STATUS_BUSY if self._busy else 0
        return _ERROR.put(cci.STATUS_READY | busy, self._error & 0xFF)

    def on_read(self, length: int) -> bytes:
        status_read = self._pointer <= cci.REG_STATUS < self._pointer + length
        self.values[cci.REG_STATUS] = self._status()
        data = super().on_read(length)
        if status_read:
            if self._booting:
                self._booting -= 1
            elif self._busy:
                self._busy -= 1
        return data

    def on_register_write(self, address: int, value: int) -> None:
        if address == cci.REG_STATUS or self._booting:
            return  # read-only; a booting camera ignores the host
        self.values[address] = value
        if address == cci.REG_COMMAND and not self._busy:
            self.commands_run.append(value)
            self._error = self._execute(value)
            self._busy = self.sim_ffc_polls if value == self._ffc_word else self.sim_busy_polls

    @property
    def _ffc_word(self) -> int:
        return cci.COMMANDS["SYS_RUN_FFC"].id(cci.CommandType.RUN)

    def _data(self, words: int) -> list[int]:
        return [self.values[cci.REG_DATA0 + 2 * i] for i in range(words)]

    def _put(self, words: list[int]) -> None:
        for i, w in enumerate(words):
            self.values[cci.REG_DATA0 + 2 * i] = w

    def _execute(self, word: int) -> int:
        """Run a command word; return the error code (0 = success)."""
        command = self._by_base.get(word & ~0x3)
        if word & 0x3 == 0x3 or command is None:
            return ERROR_UNDEFINED
        kind = cci.CommandType(word & 0x3)
        if kind not in command.kinds:
            return ERROR_UNDEFINED
        if kind is cci.CommandType.RUN:
            if command.name == "SYS_RUN_FFC":
                self.ffc_count += 1
                self.last_ffc_frame = self.frame
            return 0
        if self.values[cci.REG_DATA_LENGTH] != command.words:
            return ERROR_DATA_SIZE
        if kind is cci.CommandType.GET:
            self._put(cci.words_of(self._value(command.name), command.words))
            return 0
        value = cci.value_of(self._data(command.words))
        if value not in _ENUMS[command.name][1]:
            return ERROR_RANGE
        self.attributes[command.name] = value
        return 0

    def _value(self, name: str) -> int:
        if name == "SYS_FPA_TEMPERATURE":
            return round(self.sim_fpa_temperature_k * 100)
        if name == "SYS_AUX_TEMPERATURE":
            return round((self.sim_fpa_temperature_k - 2.0) * 100)
        if name == "SYS_UPTIME":
            return round(self.frame * 1e6 / spec.FP1000S) & 0xFFFFFFFF
        return self.attributes[name]

    # -- what the FPGA needs -----------------------------------------------------------------

    def latch(self, frame: int) -> None:
        """Frame ``frame`` starts; CCI settings act at once, so nothing is pending."""
        self.frame = frame

    def timing(self) -> SensorTiming:
        rows = spec.HEIGHT
        return SensorTiming(
            row_s=1000 / spec.FP1000S / rows, frame_rows=rows, exposure_rows=0, height=rows
        )

    def is_snapshot(self) -> bool:
        return False

    def image_registers(self) -> dict[str, int]:
        """The CCI state shaping this frame (recorded with it)."""
        return {
            **self.attributes,
            "FPA_CENTI_K": round(self.sim_fpa_temperature_k * 100),
            "FRAME_COUNTER": self.frame,
            "UPTIME_MS": self._value("SYS_UPTIME"),
            "FFC_STATE": FFC_DONE if self.ffc_count else FFC_NEVER,
        }

    def render(self, record: FrameRecord, context: ImageContext) -> NDArray[np.uint16]:
        r: Mapping[str, int] = record.registers
        intrinsics, rng = context.intrinsics, context.rng
        if (intrinsics.width, intrinsics.height) != (spec.WIDTH, spec.HEIGHT):
            raise ValueError(
                f"Lepton intrinsics {intrinsics.width}x{intrinsics.height}; allowed: 160x120"
            )
        rgb = render_radiance(context.world, intrinsics, record.pose, time_s=record.start_s)
        kelvin = SCENE_MIN_K + SCENE_SPAN_K * np.clip(rgb.mean(axis=2), 0.0, None)
        if rng is not None:
            kelvin = kelvin + rng.normal(0.0, NETD_K, kelvin.shape)
        fpa_k = r["FPA_CENTI_K"] / 100
        if r["RAD_ENABLE"] and r["RAD_TLINEAR_ENABLE"]:
            counts = kelvin / spec.TLINEAR_RESOLUTIONS_K[r["RAD_TLINEAR_RESOLUTION"]]
            image = np.clip(np.rint(counts), 0, 0xFFFF).astype(np.uint16)
        else:
            counts = RAW_AT_FPA + RAW_PER_K * (kelvin - fpa_k)
            image = np.clip(np.rint(counts), 0, 0x3FFF).astype(np.uint16)
        if not r["SYS_TELEMETRY_ENABLE"]:
            return image
        telemetry = telemetry_rows(
            frame_counter=r["FRAME_COUNTER"],
            uptime_ms=r["UPTIME_MS"],
            fpa_centi_k=r["FPA_CENTI_K"],
            frame_mean=round(float(image.mean())),
            ffc_state=r["FFC_STATE"],
            tlinear=bool(r["RAD_ENABLE"] and r["RAD_TLINEAR_ENABLE"]),
            resolution_code=r["RAD_TLINEAR_RESOLUTION"],
        )
        if r["SYS_TELEMETRY_LOCATION"] == spec.TELEMETRY_FOOTER:
            return np.ascontiguousarray(np.vstack([image, telemetry]))
        return np.ascontiguousarray(np.vstack([telemetry, image]))
