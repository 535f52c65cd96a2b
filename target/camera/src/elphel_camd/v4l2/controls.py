"""Frame parameters through V4L2 controls, for a sensor a kernel driver owns.

`ControlMap` says which of Elphel's parameters a node's controls can carry and converts
between the two: EXPOS (µs) from V4L2_CID_EXPOSURE's lines through the pixel rate and the
line length (width + HBLANK), or from EXPOSURE_ABSOLUTE's 100 µs units; the colour gains
(16.16) to ANALOGUE_GAIN, DIGITAL_GAIN or GAIN by the sensor's model; FLIPH/FLIPV to
HFLIP/VFLIP. A parameter without a control is not offered. Control ids: the kernel's
include/uapi/linux/v4l2-controls.h.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from elphel_camd.errors import ControlRefusedError
from elphel_camd.sensors import imx219
from elphel_camd.v4l2.source import ControlInfo

CID_EXPOSURE = 0x00980911
CID_AUTOGAIN = 0x00980912
CID_GAIN = 0x00980913
CID_HFLIP = 0x00980914
CID_VFLIP = 0x00980915
CID_EXPOSURE_AUTO = 0x009A0901
CID_EXPOSURE_ABSOLUTE = 0x009A0902
CID_VBLANK = 0x009E0901
CID_HBLANK = 0x009E0902
CID_ANALOGUE_GAIN = 0x009E0903
CID_PIXEL_RATE = 0x009F0902
CID_DIGITAL_GAIN = 0x009F0905

EXPOSURE_AUTO_MANUAL = 1  # V4L2_EXPOSURE_MANUAL
COLOUR_GAINS = ("GAINR", "GAING", "GAINGB", "GAINB")
UNITY = 0x10000  # gain 1.0 in 16.16


@dataclass(frozen=True)
class GainLaw:
    """How a gain control's value relates to the gain it applies.

    ``kind`` is ``"linear"`` (gain = value / unity) or ``"imx219_analogue"`` (the IMX219's
    analogue code: gain = 256 / (256 - code)).
    """

    kind: str = "linear"
    unity: int | None = None  # None: the control's default value is gain 1.0

    def gain(self, value: int, info: ControlInfo) -> float:
        if self.kind == "imx219_analogue":
            return imx219.analogue_gain(value)
        return value / (self.unity or info.default or 1)

    def value(self, gain: float, info: ControlInfo) -> int:
        if self.kind == "imx219_analogue":
            return imx219.analogue_gain_code(gain)
        return round(gain * (self.unity or info.default or 1))


# Gain laws by the kernel driver's name (the sensor subdevice's or card's first word).
GAIN_LAWS: dict[str, dict[int, GainLaw]] = {
    "imx219": {
        CID_ANALOGUE_GAIN: GainLaw("imx219_analogue"),
        CID_DIGITAL_GAIN: GainLaw("linear", 0x100),
    },
    "mt9p031": {CID_GAIN: GainLaw("linear", 8)},
    "mt9p006": {CID_GAIN: GainLaw("linear", 8)},
}
GAIN_CONTROLS = (CID_ANALOGUE_GAIN, CID_DIGITAL_GAIN, CID_GAIN)
# Controls that carry a parameter: a node with none of them leaves the controls to its
# sensor subdevice (a media-controller camera).
PARAMETER_CONTROLS = frozenset(
    {CID_EXPOSURE, CID_EXPOSURE_ABSOLUTE, *GAIN_CONTROLS, CID_HFLIP, CID_VFLIP}
)


class ControlMap:
    """Elphel parameters <-> one node's V4L2 controls.

    Parameters
    ----------
    controls
        The node's controls by id.
    model
        The kernel driver's name, to pick gain laws (`GAIN_LAWS`); unknown models take a
        gain control's default value as 1.0.
    """

    def __init__(self, controls: Mapping[int, ControlInfo], *, model: str) -> None:
        self.controls = {
            i: c
            for i, c in controls.items()
            if not c.read_only or i in (CID_PIXEL_RATE, CID_HBLANK)
        }
        laws = GAIN_LAWS.get(model.split()[0].lower() if model else "", {})
        self.gains = {cid: laws.get(cid, GainLaw()) for cid in GAIN_CONTROLS if self._writable(cid)}
        self.line_exposure = self._writable(CID_EXPOSURE) and all(
            c in self.controls for c in (CID_PIXEL_RATE, CID_HBLANK)
        )
        self.absolute_exposure = not self.line_exposure and self._writable(CID_EXPOSURE_ABSOLUTE)

    def _writable(self, cid: int) -> bool:
        info = self.controls.get(cid)
        return info is not None and not info.read_only

    @property
    def offered(self) -> frozenset[str]:
        """The parameters these controls carry."""
        names: set[str] = set()
        if self.line_exposure or self.absolute_exposure:
            names.add("EXPOS")
        if self.gains:
            names.update(COLOUR_GAINS)
        if self._writable(CID_HFLIP):
            names.add("FLIPH")
        if self._writable(CID_VFLIP):
            names.add("FLIPV")
        return frozenset(names)

    def read_ids(self) -> list[int]:
        """Controls to read back for each frame."""
        ids = [*self.gains]
        if self.line_exposure:
            ids += [CID_EXPOSURE, CID_HBLANK, CID_PIXEL_RATE]
        elif self.absolute_exposure:
            ids.append(CID_EXPOSURE_ABSOLUTE)
        ids += [c for c in (CID_HFLIP, CID_VFLIP) if self._writable(c)]
        return ids

    def ids_of(self, names: list[str]) -> list[int]:
        """The controls that carry these parameters."""
        ids: list[int] = []
        if "EXPOS" in names and self.line_exposure:
            ids.append(CID_EXPOSURE)
        elif "EXPOS" in names and self.absolute_exposure:
            ids.append(CID_EXPOSURE_ABSOLUTE)
        if set(names) & set(COLOUR_GAINS):
            ids += list(self.gains)
        ids += [c for n, c in (("FLIPH", CID_HFLIP), ("FLIPV", CID_VFLIP)) if n in names]
        return [c for c in ids if self._writable(c)]

    def line_time_s(self, width: int, values: Mapping[int, int]) -> float:
        """Seconds of one line: (width + HBLANK) pixels at the pixel rate."""
        return (width + values[CID_HBLANK]) / values[CID_PIXEL_RATE]

    def limits(self, *, width: int, timing: Mapping[int, int]) -> dict[str, tuple[int, int]]:
        """The range of each offered parameter that the driver's control limits allow."""
        out: dict[str, tuple[int, int]] = {}
        if self.line_exposure:
            info, line_s = self.controls[CID_EXPOSURE], self.line_time_s(width, timing)
            low = max(1, round(info.minimum * line_s * 1e6))
            out["EXPOS"] = (low, max(low, round(info.maximum * line_s * 1e6)))
        elif self.absolute_exposure:
            info = self.controls[CID_EXPOSURE_ABSOLUTE]
            out["EXPOS"] = (max(1, info.minimum * 100), info.maximum * 100)
        if self.gains:
            least = most = 1.0
            for cid, law in self.gains.items():
                info = self.controls[cid]
                least *= law.gain(info.minimum, info)
                most *= law.gain(info.maximum, info)
            span = (max(round(least * UNITY), UNITY), max(round(most * UNITY), UNITY))
            out.update(dict.fromkeys(COLOUR_GAINS, span))
        return out

    # -- parameters -> controls ------------------------------------------------------------

    def to_controls(
        self, state: Mapping[str, int], *, width: int, timing: Mapping[int, int]
    ) -> dict[int, int]:
        """Control values for a parameter state (ControlRefusedError outside the driver's limits).

        ``timing`` holds the current HBLANK and PIXEL_RATE for line-based exposure.
        """
        out: dict[int, int] = {}
        if self.line_exposure:
            lines = round(state["EXPOS"] * 1e-6 / self.line_time_s(width, timing))
            out[CID_EXPOSURE] = self._checked("EXPOS", state["EXPOS"], CID_EXPOSURE, lines)
        elif self.absolute_exposure:
            units = round(state["EXPOS"] / 100)
            out[CID_EXPOSURE_ABSOLUTE] = self._checked(
                "EXPOS", state["EXPOS"], CID_EXPOSURE_ABSOLUTE, units
            )
        if self.gains:
            out.update(self._gain_values(state["GAING"]))
        for name, cid in (("FLIPH", CID_HFLIP), ("FLIPV", CID_VFLIP)):
            if self._writable(cid):
                out[cid] = self._checked(name, state[name], cid, state[name])
        return out

    def _gain_values(self, gain_16: int) -> dict[int, int]:
        """Analogue gain first, up to its maximum; the digital stage takes the rest."""
        remaining = gain_16 / UNITY
        out: dict[int, int] = {}
        stages = list(self.gains.items())
        for k, (cid, law) in enumerate(stages):
            info = self.controls[cid]
            last = k == len(stages) - 1
            top = law.gain(info.maximum, info)
            applied = remaining if last else min(remaining, top)
            value = law.value(applied, info)
            if not last:
                value = max(info.minimum, min(value, info.maximum))
            out[cid] = self._checked("GAING", gain_16, cid, value)
            remaining /= max(law.gain(out[cid], info), 1e-9)
        return out

    def _checked(self, name: str, asked: int, cid: int, value: int) -> int:
        info = self.controls[cid]
        step = max(info.step, 1)
        if info.minimum <= value <= info.maximum and (value - info.minimum) % step == 0:
            return value
        raise ControlRefusedError(
            name,
            asked,
            f"control {info.name!r} takes {info.minimum}..{info.maximum} step {step} "
            f"(the driver's limits); {name}={asked} needs {value}",
        )

    # -- controls -> parameters ------------------------------------------------------------

    def to_params(self, values: Mapping[int, int], *, width: int) -> dict[str, int]:
        """The parameters that control values read back from the driver mean."""
        out: dict[str, int] = {}
        if self.line_exposure and CID_EXPOSURE in values:
            lines = values[CID_EXPOSURE]
            out["EXPOS"] = round(lines * self.line_time_s(width, values) * 1e6)
            out["VEXPOS"] = lines
        elif self.absolute_exposure and CID_EXPOSURE_ABSOLUTE in values:
            out["EXPOS"] = values[CID_EXPOSURE_ABSOLUTE] * 100
        if self.gains:
            gain = 1.0
            for cid, law in self.gains.items():
                if cid in values:
                    gain *= law.gain(values[cid], self.controls[cid])
            out.update(dict.fromkeys(COLOUR_GAINS, round(gain * UNITY)))
        for name, cid in (("FLIPH", CID_HFLIP), ("FLIPV", CID_VFLIP)):
            if cid in values:
                out[name] = int(bool(values[cid]))
        return out
