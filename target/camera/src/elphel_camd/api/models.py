"""Pydantic models of the REST API, the parameter ones generated from `PARAMS`.

Every frame parameter becomes a field with its unit and fixed limits, so the OpenAPI
schema documents each name. The fixed limits are the widest any sensor allows, with what
holds on every sensor (window edges and sizes even, TRIG one of 0, 4, 20); a value
outside them is 422. The port's sensor driver narrows them (e.g. WOI_WIDTH <= 2592 on the
MT9P006, the window inside the sensor) and refuses the rest with 409 and the range that
applies. `EVENT_SCHEMA` describes one server-sent event of ``GET /events``.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field, create_model

from elphel_camd.events import EVENT_TYPES
from elphel_camd.params import PARAMS, TRIG_VALUES, ParamSpec

STRICT = ConfigDict(extra="forbid")

# What the schema states beyond the fixed limits, because every sensor requires it.
EVEN = frozenset({"WOI_LEFT", "WOI_TOP", "WOI_WIDTH", "WOI_HEIGHT", "PF_HEIGHT"})
ENUMS: dict[str, tuple[int, ...]] = {"TRIG": TRIG_VALUES}


def schema_allowed(spec: ParamSpec) -> str:
    """What the schema allows for a parameter, as a 422 answer names it."""
    if spec.name in ENUMS:
        return f"one of {', '.join(map(str, ENUMS[spec.name]))}"
    even = " (even)" if spec.name in EVEN else ""
    return f"an integer {spec.minimum}..{spec.maximum}{even} [{spec.unit}]"


def _drop_default(schema: dict[str, Any]) -> None:
    schema.pop("default", None)


def _field(spec: ParamSpec) -> Any:
    extra: dict[str, Any] = {"unit": spec.unit}
    if spec.read_only:
        extra["readOnly"] = True
    description = f"{spec.doc} [{spec.unit}]" + (" (read-only)" if spec.read_only else "")
    if spec.name in ENUMS:
        extra["enum"] = list(ENUMS[spec.name])
    return Field(
        default=None,
        ge=spec.minimum,
        le=spec.maximum,
        multiple_of=2 if spec.name in EVEN else None,
        strict=True,
        description=description,
        json_schema_extra=extra,
    )


def whole_number(value: Any) -> Any:
    """A float that is a whole number (6396.0: an integer to JSON Schema) as an int."""
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return value


Integer = Annotated[int, BeforeValidator(whole_number)]


def _enum_type(allowed: tuple[int, ...]) -> Any:
    def check(value: int) -> int:
        if value not in allowed:
            raise ValueError(f"not one of {', '.join(map(str, allowed))}")
        return value

    return Annotated[int, BeforeValidator(whole_number), AfterValidator(check)]


def _params_model(name: str, specs: list[ParamSpec], doc: str) -> type[BaseModel]:
    fields: dict[str, Any] = {
        spec.name: (_enum_type(ENUMS[spec.name]) if spec.name in ENUMS else Integer, _field(spec))
        for spec in specs
    }
    config = ConfigDict(extra="forbid", json_schema_extra=_drop_defaults)
    model: type[BaseModel] = create_model(name, __config__=config, __doc__=doc, **fields)
    return model


def _drop_defaults(schema: dict[str, Any]) -> None:
    # Absent means "unchanged" (PATCH) or "not on this sensor" (GET); null is never valid.
    for prop in schema.get("properties", {}).values():
        _drop_default(prop)


ParamsPatch = _params_model(
    "ParamsPatch",
    [s for s in PARAMS.values() if not s.read_only],
    "Writable frame parameters to change; all are applied or none.",
)
Params = _params_model(
    "Params",
    list(PARAMS.values()),
    "Frame parameters of a port (the sensor's own limits may be narrower).",
)


class Problem(BaseModel):
    """An error: what went wrong; for a rejected value, the parameter, value and range."""

    model_config = ConfigDict(extra="allow")

    detail: str
    error: str
    parameter: str | None = None
    value: Any = None
    allowed: str | None = None


class PatchResult(BaseModel):
    model_config = STRICT

    frame: int = Field(
        description="frame from which this request's values are in effect, as scheduled when "
        "the answer was made (no other write came in between); a later write of the same "
        "parameter for the same or an earlier frame replaces it: the last write wins"
    )
    params: Params  # type: ignore[valid-type]


class FrameInfo(BaseModel):
    model_config = STRICT

    port: int
    frame: int
    timestamp_ns: int


class SensorInfo(BaseModel):
    model_config = ConfigDict(extra="allow")

    model: str
    chip_id: int
    i2c_address: int
    sensor_code: int
    bayer: str | None
    bits: int


class PortInfo(BaseModel):
    model_config = ConfigDict(extra="allow")

    port: int
    sensor: SensorInfo | None
    frame: int | None = None


class Info(BaseModel):
    model_config = ConfigDict(extra="allow")

    board: str
    daemon: str
    version: str
    capabilities: list[str]
    ports: list[PortInfo]


class PortHealth(BaseModel):
    model_config = ConfigDict(extra="allow")

    port: int
    sensor: str | None
    ok: bool
    frame: int | None = None
    error: str | None = None
    detail: str | None = None
    stream: dict[str, Any] | None = Field(
        None,
        description="the port's frame stream where the board has one (v4l2, lepton): "
        "its state (streaming when frames come) and counts",
    )


class Health(BaseModel):
    model_config = ConfigDict(extra="allow")

    status: str = Field(
        description="ok, or degraded when a port's I2C bus fails or its frame stream "
        "stopped (HTTP 503)"
    )
    board: str
    uptime_s: float
    ports: list[PortHealth]
    error: str | None = None
    detail: str | None = None


class RegisterFieldInfo(BaseModel):
    """A bit field a register declares: bits ``msb..lsb`` (``lsb == msb`` for one bit)."""

    model_config = STRICT

    name: str
    msb: int
    lsb: int
    doc: str


class RegisterValue(BaseModel):
    model_config = STRICT

    port: int
    name: str
    address: int
    value: int
    access: str
    minimum: int
    maximum: int
    unit: str
    doc: str
    fields: dict[str, int] = Field(
        default_factory=dict, description="the value decoded into the register's bit fields"
    )


class RegisterWrite(BaseModel):
    """The value to write to a raw register (checked against the register table)."""

    model_config = STRICT

    value: Integer = Field(strict=True, ge=0, le=0xFFFF)


class RegisterEntry(BaseModel):
    model_config = STRICT

    name: str
    address: int
    access: str
    reset: int
    minimum: int
    maximum: int
    width: int
    unit: str
    doc: str
    fields: list[RegisterFieldInfo] = Field(
        default_factory=list, description="the register's declared bit fields"
    )


def _json_data(properties: dict[str, Any], required: list[str]) -> dict[str, Any]:
    return {
        "type": "string",
        "contentMediaType": "application/json",
        "contentSchema": {"type": "object", "properties": properties, "required": required},
    }


_INT = {"type": "integer"}
_EVENT_DATA: dict[str, dict[str, Any]] = {
    "frame": _json_data(
        {"port": _INT, "frame": _INT, "timestamp_ns": _INT}, ["port", "frame", "timestamp_ns"]
    ),
    "params": _json_data(
        {
            "port": _INT,
            "frame": _INT,
            "changes": {"type": "object", "additionalProperties": _INT},
            "register": {"type": "string"},
        },
        ["port", "frame"],
    ),
    "error": _json_data(
        {"port": _INT, "frame": _INT, "error": {"type": "string"}, "detail": {"type": "string"}},
        ["port", "error", "detail"],
    ),
    "dropped": _json_data({"dropped": _INT}, ["dropped"]),
}
_EVENT_FIELDS = {
    "id": {"type": "string", "pattern": "^[0-9]+$", "description": "the event's sequence number"},
    "retry": {"type": "integer", "minimum": 0},
}


def _event(type_: str) -> dict[str, Any]:
    return {
        "type": "object",
        "title": f"{type_} event",
        "required": ["event", "data"],
        "properties": {"event": {"const": type_}, "data": _EVENT_DATA[type_], **_EVENT_FIELDS},
    }


# One server-sent event as a client parses it (``event``, ``data``, ``id``, ``retry``):
# each type the hub publishes with its JSON data, ``dropped``, and any other type with a
# JSON object as data (a newer daemon may add types; clients skip what they do not know).
EVENT_SCHEMA: dict[str, Any] = {
    "anyOf": [
        *(_event(t) for t in (*EVENT_TYPES, "dropped") if t in _EVENT_DATA),
        {
            "type": "object",
            "title": "other event",
            "required": ["event", "data"],
            "properties": {
                "event": {"type": "string"},
                "data": {"type": "string", "contentMediaType": "application/json"},
                **_EVENT_FIELDS,
            },
        },
    ]
}
