"""What the host expects of elphel-camd's answers: pydantic models, checked on arrival.

A daemon (or something posing as one) may answer ``{}``, ``null``, a string where a
list belongs, a PATCH reply without ``frame`` or a frame numbered ``Infinity``. Each
answer is checked against its model here, and a mismatch becomes one
`~elphel_host.errors.DeviceAnswerError` naming the device, the field and what is
allowed. Fields the host does not use pass through untouched (newer daemons add some).
"""

from __future__ import annotations

from typing import Any, TypeVar

from pydantic import BaseModel, ConfigDict, Field, StrictInt, ValidationError

from elphel_host.errors import DeviceAnswerError
from elphel_host.shown import shown

FRAME_MAX = 2**63 - 1


class _Answer(BaseModel):
    model_config = ConfigDict(extra="allow", frozen=True)


class SensorAnswer(_Answer):
    """A port's sensor in ``/info``."""

    model: str
    bits: StrictInt = Field(ge=1, le=32)
    bayer: str | None = None
    chip_id: StrictInt | None = None
    i2c_address: StrictInt | None = None
    sensor_code: StrictInt | None = None


class PortAnswer(_Answer):
    """One port of ``/info``."""

    port: StrictInt = Field(ge=0)
    sensor: SensorAnswer | None


class InfoAnswer(_Answer):
    """``GET /info``."""

    board: str
    daemon: str
    version: str
    ports: list[PortAnswer]


class PatchAnswer(_Answer):
    """The reply of ``PATCH /ports/{port}/params``."""

    frame: StrictInt = Field(ge=0, le=FRAME_MAX)
    params: dict[str, StrictInt]


class FrameAnswer(_Answer):
    """``GET /ports/{port}/frame``."""

    port: StrictInt = Field(ge=0)
    frame: StrictInt = Field(ge=0, le=FRAME_MAX)
    timestamp_ns: StrictInt


class FrameMetadata(_Answer):
    """A captured frame's JSON metadata (the TIFF's ImageDescription)."""

    frame: StrictInt = Field(ge=0, le=FRAME_MAX)
    port: StrictInt = Field(default=0, ge=0)
    timestamp_ns: StrictInt | None = None
    bayer: str | None = None


class FrameEvent(_Answer):
    """The data of a ``frame`` event."""

    port: StrictInt = Field(ge=0)
    frame: StrictInt = Field(ge=0, le=FRAME_MAX)
    timestamp_ns: StrictInt


class ParamsEvent(_Answer):
    """The data of a ``params`` event."""

    port: StrictInt = Field(ge=0)
    frame: StrictInt = Field(ge=0, le=FRAME_MAX)


EVENT_MODELS: dict[str, type[_Answer]] = {"frame": FrameEvent, "params": ParamsEvent}

Model = TypeVar("Model", bound=BaseModel)


def checked(model: type[Model], data: Any, *, what: str) -> Model:
    """``data`` as ``model``; a mismatch raises `DeviceAnswerError` naming its first field."""
    try:
        return model.model_validate(data)
    except ValidationError as e:
        first = e.errors()[0]
        where = ".".join(str(p) for p in first["loc"]) or "the answer"
        got = shown(repr(first.get("input")), limit_chars=60)
        raise DeviceAnswerError(
            f"{what}: {where}={got}: {first['msg']} ({len(e.errors())} problem(s) in all)"
        ) from e


def checked_dict(model: type[_Answer], data: Any, *, what: str) -> dict[str, Any]:
    """``data`` checked against ``model`` and returned as the dict it was (extra fields kept)."""
    checked(model, data, what=what)
    result: dict[str, Any] = data
    return result
