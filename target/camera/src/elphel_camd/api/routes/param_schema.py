"""Route of a port's parameter description: ``GET /ports/{port}/params/schema``.

What a form needs to offer a port's parameters without knowing the sensor: for each
parameter its unit, its limits on this sensor in the current state, whether this sensor
accepts writes to it, its meaning, and how to show it (exposure in ms, gains as
multipliers, trigger modes by name). Everything comes from `elphel_camd.params.PARAMS`
and the port's driver; the browser page builds its controls from this answer.
"""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from elphel_camd.api.deps import READS, PortPath, Service
from elphel_camd.api.errors import error_responses
from elphel_camd.params import PARAMS, TRIG_VALUES
from elphel_camd.sensors import imx219, lepton35
from elphel_camd.sensors.aptina import AptinaSensor, exposure_max_us
from elphel_camd.sensors.base import SensorDriver
from elphel_camd.sensors.imx219 import IMX219
from elphel_camd.sensors.lepton35 import Lepton35
from elphel_camd.v4l2.sensor import V4L2Sensor

router = APIRouter()

# How a parameter is shown: in `unit`, value * factor (the API keeps Elphel's units).
DISPLAY: dict[str, dict[str, Any]] = {
    "EXPOS": {"unit": "ms", "factor": 1e-3, "slider": "log"},
    **{g: {"unit": "x", "factor": 1 / 0x10000} for g in ("GAINR", "GAING", "GAINGB", "GAINB")},
    "TRIG_PERIOD": {"unit": "ms", "factor": 1e-5},
    "TRIG_DELAY": {"unit": "ms", "factor": 1e-5},
    "FP1000SLIM": {"unit": "fps", "factor": 1e-3},
    "FP1000S": {"unit": "fps", "factor": 1e-3},
}
CHOICES: dict[str, dict[int, str]] = {
    "TRIG": dict(zip(TRIG_VALUES, ("free-run", "snapshot", "snapshot + GRR"), strict=True)),
    "BIN_HOR": {1: "none", 2: "x2"},
    "BIN_VERT": {1: "none", 2: "x2"},
    "FLIPH": {0: "off", 1: "on"},
    "FLIPV": {0: "off", 1: "on"},
}
EVEN = ("WOI_LEFT", "WOI_TOP", "WOI_WIDTH", "WOI_HEIGHT", "PF_HEIGHT")


def _limits(driver: SensorDriver, state: dict[str, int]) -> dict[str, tuple[int, int]]:
    """Limits narrowed to what this sensor accepts in this state."""
    out: dict[str, tuple[int, int]] = {}
    if isinstance(driver, AptinaSensor):
        width, height = driver.image_width, driver.image_height
        out["WOI_WIDTH"] = (2, width)
        out["WOI_HEIGHT"] = (2, height)
        out["WOI_LEFT"] = (0, width - state["WOI_WIDTH"])
        out["WOI_TOP"] = (0, max(height - (state["PF_HEIGHT"] or state["WOI_HEIGHT"]), 0))
        out["PF_HEIGHT"] = (0, height)
        for gain in ("GAINR", "GAING", "GAINGB", "GAINB"):
            out[gain] = (driver.gain_min, driver.gain_max)
        row_s = driver.row_time_s(state["WOI_WIDTH"])
        out["VEXPOS"] = (1, driver.exposure_rows_max)
        out["EXPOS"] = (1, exposure_max_us(row_s=row_s, max_rows=driver.exposure_rows_max))
    elif isinstance(driver, IMX219):
        out.update(_imx219_limits(driver, state))
    elif isinstance(driver, Lepton35):
        out.update(WOI_LEFT=(0, 0), WOI_TOP=(0, 0), WOI_WIDTH=(lepton35.WIDTH, lepton35.WIDTH))
        out["WOI_HEIGHT"] = (lepton35.HEIGHT, lepton35.HEIGHT_TELEMETRY)
        out["TRIG"] = (0, 0)
    elif isinstance(driver, V4L2Sensor):
        out.update(driver.limits())
        out["TRIG"] = (0, 0)
    return out


def _imx219_limits(driver: IMX219, state: dict[str, int]) -> dict[str, tuple[int, int]]:
    """The IMX219's window, gain and exposure limits in this state."""
    width, height = driver.image_width, driver.image_height
    row_s = driver.row_time_s()
    longest = driver.exposure_rows_max
    return {
        "WOI_WIDTH": (2, width),
        "WOI_HEIGHT": (2, height),
        "WOI_LEFT": (0, width - state["WOI_WIDTH"]),
        "WOI_TOP": (0, height - state["WOI_HEIGHT"]),
        **{gain: (driver.gain_min, driver.gain_max) for gain in imx219.GAIN_PARAMS},
        "VEXPOS": (imx219.EXPOSURE_LINES_MIN, longest),
        "EXPOS": (1, imx219.lines_to_us(longest, row_s=row_s)),
    }


def window_of(driver: SensorDriver) -> dict[str, int] | None:
    """The sensor's full window and the step of its edges (None if the window is fixed)."""
    if isinstance(driver, (AptinaSensor, IMX219)):
        return {"width": driver.image_width, "height": driver.image_height, "step": 2}
    if isinstance(driver, V4L2Sensor):
        return driver.window()
    return None


@router.get(
    "/ports/{port}/params/schema",
    dependencies=READS,
    responses=error_responses(401, 404, 503),
)
def get_param_schema(service: Service, port: PortPath) -> JSONResponse:
    """Each parameter of a port: unit, limits on this sensor now, writable, meaning, display.

    ``window`` gives the sensor's full size and the step of the window's edges (null
    when the sensor's window is fixed).
    """
    driver = service.sensor(port)
    state = service.params(port)
    limits = _limits(driver, state)
    params: dict[str, Any] = {}
    for name, spec in PARAMS.items():
        low, high = limits.get(name, (spec.minimum, spec.maximum))
        entry: dict[str, Any] = {
            "unit": spec.unit,
            "minimum": low,
            "maximum": high,
            "writable": name in driver.writable and not spec.read_only,
            "read_only": spec.read_only,
            "doc": spec.doc,
        }
        if name in EVEN:
            entry["step"] = 2
        if name in DISPLAY:
            entry["display"] = DISPLAY[name]
        if name in CHOICES:
            entry["choices"] = {str(k): v for k, v in CHOICES[name].items()}
        params[name] = entry
    return JSONResponse(
        {
            "port": port,
            "sensor": driver.model,
            "bayer": driver.bayer,
            "window": window_of(driver),
            "capabilities": sorted(service.board.capabilities),
            "params": params,
        }
    )
