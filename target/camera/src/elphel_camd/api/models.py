"""Pydantic models of the REST API, the parameter ones generated from `PARAMS`.

Every frame parameter becomes a field with its unit and fixed limits, so the OpenAPI
schema documents each name. The fixed limits are the widest any sensor allows; the
sensor driver narrows them (e.g. WOI_WIDTH <= 2592 on the MT9P006) and answers 422 with
the range that applies.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field, create_model

from elphel_camd.params import PARAMS, ParamSpec

STRICT = ConfigDict(extra="forbid")


def _drop_default(schema: dict[str, Any]) -> None:
    schema.pop("default", None)


def _field(spec: ParamSpec) -> Any:
    return Field(
        default=None,
        ge=spec.minimum,
        le=spec.maximum,
        strict=True,
        description=f"{spec.doc} [{spec.unit}]" + (" (read-only)" if spec.read_only else ""),
        json_schema_extra={"unit": spec.unit, **({"readOnly": True} if spec.read_only else {})},
    )


def _params_model(name: str, specs: list[ParamSpec], doc: str) -> type[BaseModel]:
    fields: dict[str, Any] = {spec.name: (int, _field(spec)) for spec in specs}
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

    frame: int = Field(description="frame at which the change is in effect")
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


class Health(BaseModel):
    model_config = ConfigDict(extra="allow")

    status: str = Field(description="ok, or degraded when a port's I2C bus fails (HTTP 503)")
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

    value: int = Field(strict=True, ge=0, le=0xFFFF)


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
