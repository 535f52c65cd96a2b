"""FLIR Lepton 3.5 (160 x 120 LWIR, radiometric): a command-protocol (CCI) driver.

Facts: shared/reference/sensors.md section 5 (CCI registers and commands, power-on
defaults, Elphel's Lepton behaviour) and 3.5 (the clamps Elphel applies). The Lepton has
no frame-synchronised registers: window and trigger are fixed (160 x 120, 122 rows with the
telemetry footer; free-running at 8.7 fps), and its settings are CCI commands, issued at
once. Telemetry follows WOI_HEIGHT, as Elphel's driver does; the rest (radiometry, TLinear,
FFC, VSYNC) are methods.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

from elphel_camd.errors import I2CError, ParameterRangeError, UnsupportedError
from elphel_camd.i2c.bus import I2CBus
from elphel_camd.i2c.regio import RegisterIO
from elphel_camd.params import (
    EXPOSURE,
    FUNCTIONS,
    GAINS,
    LIMITFPS,
    TRIG_PERIOD_MIN_REPEAT,
    TRIGGERMODE,
    TRIGSEQ,
    WINDOW,
    check_range,
)
from elphel_camd.sensors import cci
from elphel_camd.sensors.base import State
from elphel_camd.sensors.command import CommandSensor

MODEL = "LEPTON35"
I2C_ADDRESS = 0x2A
SENSOR_CODE = 0x44  # Elphel's SENSOR_LEPTON35
WIDTH = 160
HEIGHT = 120
HEIGHT_TELEMETRY = 122  # two telemetry rows (footer)
PIXEL_PITCH_UM = 12.0
BITS = 16
FP1000S = 8700  # unique frames just below 9 Hz; Elphel reports 8.7 fps
GPIO_MODE_GPIO = 0
GPIO_MODE_VSYNC = 5
TELEMETRY_FOOTER = 1
TLINEAR_RESOLUTIONS_K = {0: 0.1, 1: 0.01}  # RAD TLinear resolution enum -> kelvin per count

# Why a parameter cannot be set on the Lepton.
_UNSUPPORTED = {
    "EXPOS": "it is a microbolometer without exposure control",
    "VEXPOS": "it is a microbolometer without exposure control",
    "GAINR": "it is monochrome and has no colour gains",
    "GAING": "it is monochrome and has no colour gains",
    "GAINGB": "it is monochrome and has no colour gains",
    "GAINB": "it is monochrome and has no colour gains",
    "FLIPH": "its driver does not mirror the image",
    "FLIPV": "its driver does not mirror the image",
    "TRIG_DELAY": "it has no trigger input (it runs free at 8.7 fps)",
    "TRIG_DECIMATE": "it has no trigger input (it runs free at 8.7 fps)",
    "PF_HEIGHT": "its window is fixed at 160x120 (no photo-finish)",
    "FP1000SLIM": "its frame rate is fixed at 8.7 fps",
    "FPSFLAGS": "its frame rate is fixed at 8.7 fps",
}
_FIXED_WINDOW = "the Lepton window is fixed at 160x120, or 160x122 with telemetry"


class LeptonParameters:
    """The Lepton's parameter model: a fixed window, no trigger, 8.7 fps.

    Shared by the CCI driver and a Lepton reached by VoSPI only.
    """

    def defaults(self) -> State:
        state = {
            "WOI_LEFT": 0,
            "WOI_TOP": 0,
            "WOI_WIDTH": WIDTH,
            "WOI_HEIGHT": HEIGHT,
            "FLIPH": 0,
            "FLIPV": 0,
            "TRIG": 0,
            "TRIG_PERIOD": 0,
            "TRIG_MASTER": 0,
            "TRIG_DELAY": 0,
            "TRIG_DECIMATE": 0,
            "PF_HEIGHT": 0,
            "FP1000SLIM": 0,
            "FPSFLAGS": 0,
        }
        return self.normalize(state, frozenset())

    def normalize(self, state: Mapping[str, int], changed: frozenset[str]) -> State:
        s = dict(state)
        if s["WOI_WIDTH"] != WIDTH:
            raise ParameterRangeError("WOI_WIDTH", s["WOI_WIDTH"], f"160 ({_FIXED_WINDOW})")
        if s["WOI_HEIGHT"] not in (HEIGHT, HEIGHT_TELEMETRY):
            raise ParameterRangeError(
                "WOI_HEIGHT", s["WOI_HEIGHT"], f"120, or 122 for telemetry ({_FIXED_WINDOW})"
            )
        for name in ("WOI_LEFT", "WOI_TOP"):
            if s[name]:
                raise ParameterRangeError(name, s[name], f"0 ({_FIXED_WINDOW})")
        if s["TRIG"]:
            raise ParameterRangeError(
                "TRIG", s["TRIG"], "0 (the Lepton has no trigger input; it runs free at 8.7 fps)"
            )
        if 1 < s["TRIG_PERIOD"] < TRIG_PERIOD_MIN_REPEAT:
            raise ParameterRangeError(
                "TRIG_PERIOD", s["TRIG_PERIOD"], "0 (stop), 1 (single), >= 256"
            )
        check_range("TRIG_MASTER", s["TRIG_MASTER"], 0, 3)
        s["FP1000S"] = FP1000S
        s["SENSOR"] = SENSOR_CODE
        s["COLOR"] = 15
        s["BITS"] = BITS
        return s

    def frame_period_s(self, state: Mapping[str, int]) -> float:
        return 1000 / FP1000S


class Lepton35(LeptonParameters, CommandSensor):
    """Driver of the FLIR Lepton 3.5 through its CCI.

    Parameters
    ----------
    io
        Register access at address 0x2A with 16-bit register addresses.
    timeout_s
        How long a CCI command may keep the camera busy.
    """

    model = MODEL
    i2c_address = I2C_ADDRESS
    sensor_code = SENSOR_CODE
    bayer = None
    bits = BITS
    # No frame-synchronised registers: a setting issued one frame ahead is in effect for
    # the target frame (Elphel gives the Lepton a copy of the mt9x001 table).
    ahead: ClassVar[Mapping[str, tuple[int, int]]] = {fn: (1, 1) for fn in FUNCTIONS}
    writable = frozenset({"WOI_LEFT", "WOI_TOP", "WOI_WIDTH", "WOI_HEIGHT", "TRIG"}) | frozenset(
        {"TRIG_PERIOD", "TRIG_MASTER"}  # the board's common trigger, shared with other ports
    )

    @classmethod
    def probe(cls, bus: I2CBus, *, bus_name: str) -> Lepton35 | None:
        """A Lepton: status with reserved bits clear, boot completed, answers a ping."""
        io = RegisterIO(
            bus,
            cls.i2c_address,
            reg_bytes=cci.REGISTERS.address_bytes,
            bus_name=bus_name,
            retries=1,
        )
        try:
            status = io.read_word(cci.REG_STATUS)
        except I2CError:
            return None
        if status & cci.STATUS_RESERVED:
            return None
        driver = cls(io)
        try:
            driver.cci.wait_ready(booted=True)
            driver.ping()
        except I2CError:  # LeptonError included: whatever answers is not a working Lepton
            return None
        return driver

    # -- CCI operations --------------------------------------------------------------------

    def ping(self) -> None:
        """RUN SYS ping; raises `LeptonError` if the camera answers with an error."""
        self.run_command("SYS_PING")

    def fpa_temperature_centi_k(self) -> int:
        """Focal-plane-array temperature in 0.01 K, as the camera reports it."""
        return self.get_attribute("SYS_FPA_TEMPERATURE")

    def fpa_temperature_k(self) -> float:
        """Focal-plane-array temperature in kelvin."""
        return self.fpa_temperature_centi_k() / 100

    def run_ffc(self) -> None:
        """Run a flat-field correction now (the shutter closes for a moment)."""
        self.run_command("SYS_RUN_FFC")

    def radiometry(self) -> bool:
        return bool(self.get_attribute("RAD_ENABLE"))

    def set_radiometry(self, enable: bool) -> None:
        self.set_attribute("RAD_ENABLE", int(enable))

    def tlinear(self) -> bool:
        return bool(self.get_attribute("RAD_TLINEAR_ENABLE"))

    def set_tlinear(self, enable: bool) -> None:
        """TLinear on: pixels are scene temperatures (at `tlinear_resolution_k`)."""
        self.set_attribute("RAD_TLINEAR_ENABLE", int(enable))

    def tlinear_resolution_k(self) -> float:
        return TLINEAR_RESOLUTIONS_K[self.get_attribute("RAD_TLINEAR_RESOLUTION")]

    def set_tlinear_resolution_k(self, kelvin: float) -> None:
        """TLinear pixel unit: 0.01 K or 0.1 K."""
        for code, k in TLINEAR_RESOLUTIONS_K.items():
            if abs(kelvin - k) < 1e-9:
                self.set_attribute("RAD_TLINEAR_RESOLUTION", code)
                return
        raise ParameterRangeError("tlinear_resolution_k", kelvin, "0.01 or 0.1")

    def gpio_mode(self) -> int:
        """OEM GPIO mode: 0 GPIO ... 5 VSYNC on GPIO3."""
        return self.get_attribute("OEM_GPIO_MODE")

    def set_vsync(self, enable: bool) -> None:
        """Frame pulse on GPIO3 (OEM GPIO mode 5), or plain GPIO (mode 0)."""
        self.set_attribute("OEM_GPIO_MODE", GPIO_MODE_VSYNC if enable else GPIO_MODE_GPIO)

    def telemetry(self) -> bool:
        return bool(self.get_attribute("SYS_TELEMETRY_ENABLE"))

    # -- parameter model -------------------------------------------------------------------

    def init(self) -> None:
        """Elphel's init list: VSYNC on GPIO3, telemetry off, telemetry location footer."""
        self.cci.wait_ready(booted=True)
        self.set_attribute("OEM_GPIO_MODE", GPIO_MODE_VSYNC)
        self.set_attribute("SYS_TELEMETRY_ENABLE", 0)
        self.set_attribute("SYS_TELEMETRY_LOCATION", TELEMETRY_FOOTER)

    def identity(self) -> dict[str, Any]:
        out = super().identity()
        out["fpa_temperature_k"] = self.fpa_temperature_k()
        return out

    def check_writable(self, names: Mapping[str, int]) -> None:
        for name in names:
            if name not in self.writable:
                why = _UNSUPPORTED.get(name, "it has no such control")
                raise UnsupportedError(f"{self.model} does not support setting {name}: {why}")

    def program(self, function: str, state: Mapping[str, int]) -> list[str]:
        """Issue the CCI commands of a function; return the attributes set.

        The Lepton has no frame-synchronised registers: only the window (telemetry rows)
        sets anything.
        """
        if function == WINDOW:
            telemetry = int(state["WOI_HEIGHT"] == HEIGHT_TELEMETRY)
            if self.set_attribute("SYS_TELEMETRY_ENABLE", telemetry):
                return ["SYS_TELEMETRY_ENABLE"]
        elif function not in (EXPOSURE, GAINS, LIMITFPS, TRIGGERMODE, TRIGSEQ):
            raise ValueError(f"unknown program function {function!r}; allowed: {FUNCTIONS}")
        return []
