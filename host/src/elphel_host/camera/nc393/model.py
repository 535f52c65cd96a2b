"""The parameter model a stock NC393 is checked against: elphel-camd's, for the model found.

A stock camera gives no ranges and cannot refuse a change as a whole, so the host checks
a change before writing anything, with the SAME table (`elphel_camd.params.PARAMS`) and
the same sensor driver's ``normalize`` as elphel-camd. The driver is built on a bus that
refuses every transfer: ``defaults``, ``normalize``, ``latency`` and ``actual_gains`` are
pure functions of a parameter state and never touch it.

Some parameters exist on the stock camera only and are checked here: ``COLOR`` (0 mono
JPEG, 2 JP46, 5 JP4, 15 raw 16-bit TIFF), ``BITS`` (8, 16), ``QUALITY`` (JPEG %, 1..100)
and the gamma words ``GTAB_R/G/GB/B`` (black level, gamma, scale).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from smbus2 import i2c_msg

from elphel_camd.errors import I2CError, ParameterRangeError
from elphel_camd.errors import UnsupportedError as CamdUnsupportedError
from elphel_camd.i2c.regio import RegisterIO
from elphel_camd.params import COMMON_TRIGGER_PARAMS, PARAMS, functions_of
from elphel_camd.sensors import MT9F002, MT9P006, Lepton35, SensorDriver
from elphel_host.errors import CameraParameterError, ReadBackError, UnsupportedError

# SENSOR codes (reference sensors.md 3.5) and the names `info()` gives them.
SENSOR_NAMES = {0x34: "MT9P006", 0x38: "MT9F002", 0x44: "LEPTON35", 0x48: "Boson640"}
DRIVERS: dict[int, type[SensorDriver]] = {0x34: MT9P006, 0x38: MT9F002, 0x44: Lepton35}

# Writable on the stock camera only: name -> (allowed, as text; the test).
_GTAB = (
    "black << 24 | round(100 * gamma) << 16 | scale (0x400 = 1.0), gamma 0.13..2.55 "
    "(e.g. 0x0A390400: black 10/256, gamma 0.57)",
    lambda v: 0 <= v <= 0xFFFFFFFF and (v >> 16) & 0xFF >= 13,
)
STOCK_ONLY: dict[str, tuple[str, Callable[[int], bool]]] = {
    "COLOR": (
        "0 (mono JPEG), 2 (JP46), 5 (JP4) or 15 (raw 16-bit TIFF)",
        lambda v: v in (0, 2, 5, 15),
    ),
    "BITS": ("8 or 16", lambda v: v in (8, 16)),
    "QUALITY": ("1..100 (JPEG quality %)", lambda v: 1 <= v <= 100),
    **dict.fromkeys(("GTAB_R", "GTAB_G", "GTAB_GB", "GTAB_B"), _GTAB),
}
# parsedit.php schedules at most this many frames ahead without blocking (its maxahead).
MAX_AHEAD = 6
# Computed by the model from the others: read back, never compared with a request.
_DERIVED = ("FP1000S", "SENSOR", "COLOR", "BITS")


class _RefusingBus:
    """An I2C bus that refuses every transfer: the model must not need the chip."""

    def i2c_rdwr(self, *msgs: i2c_msg) -> None:
        address = msgs[0].addr if msgs else 0
        raise I2CError(
            "the stock-camera parameter model has no I2C bus",
            bus="none",
            address=address,
            register=None,
        )


def sensor_name(code: int) -> str:
    """The model name of a SENSOR code; ``0x..`` for a code not in Elphel's list."""
    return SENSOR_NAMES.get(code, f"unknown sensor 0x{code:02x}")


@dataclass(frozen=True)
class Checked:
    """A change checked against the model: the state it gives and how early it may land."""

    changes: dict[str, int]
    state: dict[str, int]
    min_ahead: int


class StockModel:
    """elphel-camd's parameter model for the sensor a stock camera reports on one port.

    Parameters
    ----------
    code
        The port's ``SENSOR`` value.
    port
        The sensor port (for messages and the master-port rule).

    Raises
    ------
    UnsupportedError
        A sensor without a driver here (the Boson 640, an unknown code): it is named.
    """

    def __init__(self, code: int, *, port: int) -> None:
        kind = DRIVERS.get(code)
        if kind is None:
            raise UnsupportedError(
                f"port {port}: sensor {sensor_name(code)} (SENSOR 0x{code:02x}) has no "
                f"parameter model; supported: {', '.join(SENSOR_NAMES[c] for c in DRIVERS)}"
            )
        table = getattr(kind, "table", None)
        reg_bytes = 2 if table is None else table.address_bytes
        io = RegisterIO(_RefusingBus(), kind.i2c_address, reg_bytes=reg_bytes, bus_name="none")
        self.port = port
        self.driver: SensorDriver = kind(io)  # type: ignore[call-arg]
        defaults = self.driver.defaults()
        # What a state needs to be normalised: every parameter of the defaults but those
        # the model computes.
        self.state_names = tuple(sorted(k for k in defaults if k not in _DERIVED))

    @property
    def model(self) -> str:
        return self.driver.model

    def check(self, now: Mapping[str, int], changes: Mapping[str, int]) -> Checked:
        """Check a change against the state ``now``; nothing is written.

        Raises
        ------
        CameraParameterError
            An unknown or read-only name, a non-integer, a value out of range (the message
            and attributes name the parameter, the value and what is allowed).
        UnsupportedError
            A parameter this sensor does not take (e.g. EXPOS on the Lepton).
        """
        model_changes: dict[str, int] = {}
        for name, value in changes.items():
            if isinstance(value, bool) or not isinstance(value, int):
                raise _refused(name, value, "an integer")
            if name in STOCK_ONLY:
                text, allowed = STOCK_ONLY[name]
                if not allowed(value):
                    raise _refused(name, value, text)
                continue
            spec = PARAMS.get(name)
            if spec is None:
                known = ", ".join(sorted({*PARAMS, *STOCK_ONLY}))
                raise _refused(name, value, f"one of {known}")
            if spec.read_only:
                raise _refused(name, value, "nothing: it is read-only")
            model_changes[name] = value
        try:
            self.driver.check_writable(model_changes)
        except CamdUnsupportedError as e:
            raise UnsupportedError(f"port {self.port}: {e}") from e
        if set(COMMON_TRIGGER_PARAMS) & set(model_changes):
            master = model_changes.get("TRIG_MASTER", now.get("TRIG_MASTER", self.port))
            if master != self.port:
                name = next(n for n in COMMON_TRIGGER_PARAMS if n in model_changes)
                raise _refused(name, model_changes[name], f"set on the master port {master}")
        state = {k: now[k] for k in self.state_names if k in now}
        missing = [k for k in self.state_names if k not in now]
        if missing:
            raise CameraParameterError(
                f"port {self.port}: the camera did not report {', '.join(missing)}",
                parameter=missing[0],
                value=None,
                allowed="a value read from the camera",
            )
        try:
            normal = self.driver.normalize({**state, **model_changes}, frozenset(model_changes))
        except ParameterRangeError as e:
            raise CameraParameterError(
                f"port {self.port}: {e}", parameter=e.name, value=e.value, allowed=e.allowed
            ) from e
        new = {**normal, **{k: v for k, v in changes.items() if k in STOCK_ONLY}}
        fns = functions_of(model_changes) & set(self.driver.ahead)
        latency = max(
            (self.driver.latency(fn, s) for fn in fns for s in (state, normal)), default=1
        )
        return Checked(changes=dict(changes), state=new, min_ahead=latency + 1)

    def ahead_for(
        self, checked: Checked, *, current: int, frame: int | None, ahead: int | None
    ) -> int:
        """K of ``NAME=value*K``: ``ahead``, or ``frame`` minus the current frame.

        With neither, the earliest the change can land (its functions' latency + 1).

        Raises
        ------
        CameraParameterError
            K below that earliest.
        UnsupportedError
            K beyond `MAX_AHEAD`, parsedit.php's maxahead (further ahead the script
            blocks the request until the frame nears).
        """
        lowest = checked.min_ahead
        k = lowest if ahead is None else ahead
        if frame is not None:
            k = frame - current
        what, value = ("frame", frame) if frame is not None else ("ahead", k)
        if k < lowest:
            allowed = (
                f"frames {current + lowest}..{current + MAX_AHEAD}"
                if frame is not None
                else f"ahead {lowest}..{MAX_AHEAD}"
            )
            raise CameraParameterError(
                f"{what}={value} is too soon for {', '.join(sorted(checked.changes))} on "
                f"port {self.port} (current frame {current}); allowed: {allowed}",
                parameter=what,
                value=value,
                allowed=allowed,
            )
        if k > MAX_AHEAD:
            raise UnsupportedError(
                f"{what}={value}: a stock NC393 takes changes at most {MAX_AHEAD} frames ahead "
                f"(parsedit.php's maxahead; current frame {current})"
            )
        return k

    def check_read_back(self, checked: Checked, found: Mapping[str, int]) -> None:
        """Raise `ReadBackError` naming the first parameter the camera took differently."""
        for name, asked in checked.changes.items():
            value = found.get(name)
            if not self.confirms(name, checked, value):
                raise ReadBackError(
                    f"port {self.port}: {name}={asked} asked, {name}={value} in effect at "
                    f"frame {found.get('FRAME')} (the stock camera took the change differently)",
                    parameter=name,
                    asked=asked,
                    found=value,
                )

    def confirms(self, name: str, checked: Checked, found: int | None) -> bool:
        """Whether a value read back is what the change asked for.

        Exposure is rounded to whole rows by the camera's own driver, so ``EXPOS`` may
        differ by up to one row time; gains may be the requested value or the one the
        gain code really gives; anything else must be equal.
        """
        if found is None:
            return False
        want = checked.state[name]
        if name == "EXPOS" and checked.state.get("VEXPOS"):
            row_us = want / checked.state["VEXPOS"]
            return abs(found - want) <= max(1, math.ceil(row_us))
        if found == want:
            return True
        actual = self.driver.actual_gains(checked.state)
        return name in actual and found == actual[name]


def port_entry(port: int, code: int, frame: int | None) -> dict[str, Any]:
    """One port of `NC393Client.info`, shaped like elphel-camd's (no chip id or address).

    ``bits`` is the sensor's depth, the scale frames are decoded to (as elphel-camd
    reports it); ``supported`` says whether the sensor has a parameter model here.
    """
    entry: dict[str, Any] = {"port": port, "sensor": None}
    if not code:
        return entry
    kind = DRIVERS.get(code)
    entry["sensor"] = {
        "model": sensor_name(code),
        "sensor_code": code,
        "bayer": None if kind is None else kind.bayer,
        "bits": 16 if kind is None else kind.bits,
        "supported": kind is not None,
    }
    entry["frame"] = frame
    return entry


def _refused(name: str, value: object, allowed: str) -> CameraParameterError:
    return CameraParameterError(
        f"{name}={value!r} is out of range; allowed: {allowed}",
        parameter=name,
        value=value,
        allowed=allowed,
    )
