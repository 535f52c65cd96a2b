"""The frame parameters of a port as a user reads them: name, value, unit, range, meaning.

Units, fixed limits and meanings come from elphel-camd's own schema (its OpenAPI
document, generated from its parameter table); a stock NC393 has no schema, so the same
table (`elphel_camd.params.PARAMS`) stands in. The range that applies now — the sensor's,
for the current window and mode — comes from elphel-camd's sensor model for the port's
sensor (`StockModel`), the code the daemon checks a change with: the range it names
for a value beyond the fixed maximum is the one it would refuse with.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import httpx

from elphel_camd.params import PARAMS
from elphel_host.camera.nc393.model import StockModel
from elphel_host.errors import CameraClientError, CameraParameterError, UnsupportedError


@dataclass(frozen=True)
class ParamRow:
    name: str
    value: int | None
    unit: str
    range: str
    read_only: bool
    description: str

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def daemon_schema(url: str, *, timeout_s: float = 10.0) -> dict[str, dict[str, Any]]:
    """The ``Params`` properties of elphel-camd's OpenAPI document at ``url``."""
    try:
        response = httpx.get(f"{url.rstrip('/')}/openapi.json", timeout=timeout_s)
        response.raise_for_status()
        props: dict[str, dict[str, Any]] = response.json()["components"]["schemas"]["Params"][
            "properties"
        ]
    except (httpx.HTTPError, KeyError, ValueError) as e:
        raise CameraClientError(f"cannot read the camera's parameter schema at {url}: {e}") from e
    return props


def table_schema() -> dict[str, dict[str, Any]]:
    """The same properties from elphel-camd's parameter table (for a stock NC393)."""
    return {
        spec.name: {
            "unit": spec.unit,
            "minimum": spec.minimum,
            "maximum": spec.maximum,
            "description": f"{spec.doc} [{spec.unit}]",
            "readOnly": spec.read_only,
        }
        for spec in PARAMS.values()
    }


def _description(prop: Mapping[str, Any]) -> str:
    text = str(prop.get("description", ""))
    unit = str(prop.get("unit", ""))
    return text.replace(" (read-only)", "").removesuffix(f" [{unit}]").strip()


def _sensor_range(model: StockModel | None, now: Mapping[str, int], name: str, top: int) -> str:
    """The range the sensor model names for ``top`` (empty if it takes it)."""
    if model is None:
        return ""
    try:
        model.check(now, {name: top})
    except CameraParameterError as e:
        return e.allowed
    except UnsupportedError:
        return "not on this sensor"
    return ""


_RANGE = re.compile(r"-?\d+\.\.-?\d+( \(even\))?")


def _column_range(sensor: str, fixed: str, low: int, value: int | None) -> str:
    """The range column: the sensor's range when it is one, else the fixed one.

    A sensor's refusal that is a sentence (a rule between parameters) is not a range;
    the fixed minimum stays allowed beside a narrower sensor range when it is the value
    in effect (PF_HEIGHT 0: photo-finish off).
    """
    if not _RANGE.fullmatch(sensor):
        return fixed
    return f"{low} or {sensor}" if value == low and not sensor.startswith(f"{low}..") else sensor


def param_rows(
    schema: Mapping[str, Mapping[str, Any]],
    values: Mapping[str, int],
    *,
    sensor_code: int | None,
    port: int,
) -> list[ParamRow]:
    """One row per parameter of the schema, in the schema's order."""
    model = None
    if sensor_code:
        try:
            model = StockModel(sensor_code, port=port)
        except UnsupportedError:
            model = None
    rows = []
    for name, prop in schema.items():
        read_only = bool(prop.get("readOnly", False))
        low, high = int(prop.get("minimum", 0)), int(prop.get("maximum", 0))
        fixed = f"{low}..{high}"
        allowed = (
            "read-only"
            if read_only
            else _column_range(
                _sensor_range(model, values, name, high), fixed, low, values.get(name)
            )
        )
        rows.append(
            ParamRow(
                name=name,
                value=values.get(name),
                unit=str(prop.get("unit", "")),
                range=allowed,
                read_only=read_only,
                description=_description(prop),
            )
        )
    return rows
