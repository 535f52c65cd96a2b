"""How the API answers errors: exception -> status and code, problem bodies, 422 bodies.

Errors are JSON ``{"detail": ..., "error": ...}``; a rejected value also names
``parameter``, ``value`` and ``allowed``. Invalid input is 422, a missing port, sensor or
frame 404, a board without an image path 501, a failing I2C bus 503 (other ports keep
serving), a frame that does not come 504.
"""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from elphel_camd.api.models import Problem
from elphel_camd.errors import (
    CaptureUnavailableError,
    FrameNotAvailableError,
    FrameScheduleError,
    FrameTooEarlyError,
    FrameTooLateError,
    I2CError,
    ParameterRangeError,
    PortError,
    SensorNotFoundError,
    UnsupportedError,
)
from elphel_camd.params import PARAMS

# Exception type -> HTTP status and the body's "error" code; the first match wins.
ERROR_STATUS: tuple[tuple[type[Exception], int, str], ...] = (
    (PortError, 404, "no_such_port"),
    (SensorNotFoundError, 404, "no_sensor"),
    (FrameNotAvailableError, 404, "frame_not_available"),
    (ParameterRangeError, 422, "parameter_range"),
    (FrameTooLateError, 422, "frame_too_late"),
    (FrameTooEarlyError, 422, "frame_too_early"),
    (UnsupportedError, 422, "unsupported"),
    (CaptureUnavailableError, 501, "no_image_path"),
    (I2CError, 503, "i2c"),
    (TimeoutError, 504, "timeout"),
)

_DESCRIPTIONS = {
    401: "no or wrong bearer token",
    404: "no such port, sensor or frame",
    413: "request body too large",
    422: "invalid input: names the parameter, the value and what is allowed",
    501: "the board has no image path",
    503: "the port's I2C bus fails",
    504: "the frame did not come in time",
}

_HTTP_CODES = {401: "unauthorized", 404: "not_found", 405: "method_not_allowed"}


def error_responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    """The OpenAPI ``responses`` entries of a route's error statuses."""
    return {code: {"model": Problem, "description": _DESCRIPTIONS[code]} for code in codes}


def error_body(exc: Exception, code: str) -> dict[str, Any]:
    """The problem body of a daemon error."""
    body: dict[str, Any] = {"detail": str(exc), "error": code}
    if isinstance(exc, ParameterRangeError):
        body.update(parameter=exc.name, value=jsonable_encoder(exc.value), allowed=exc.allowed)
    elif isinstance(exc, FrameScheduleError):
        body.update(
            frame=exc.frame, this_frame=exc.this_frame, earliest=exc.earliest, latest=exc.latest
        )
    return body


def _allowed(name: str, kind: str) -> str:
    spec = PARAMS.get(name)
    if kind == "extra_forbidden":
        if spec is not None and spec.read_only:
            return "nothing: it is read-only"
        writable = sorted(n for n, s in PARAMS.items() if not s.read_only)
        return f"one of {', '.join(writable)}"
    if spec is not None:
        return f"an integer {spec.minimum}..{spec.maximum} [{spec.unit}]"
    return "see the OpenAPI schema"


def validation_problem(exc: RequestValidationError) -> dict[str, Any]:
    """A 422 body in the API's own form from FastAPI's validation errors."""
    errors = list(exc.errors())
    first = errors[0] if errors else {"loc": ("body",), "msg": "invalid", "type": "invalid"}
    loc = [str(part) for part in first.get("loc", ())]
    name = loc[-1] if len(loc) > 1 else (loc[0] if loc else "body")
    kind = str(first.get("type", ""))
    if name == "body" or kind in ("json_invalid", "model_attributes_type", "dict_type"):
        name, allowed = "body", "a JSON object"
    elif loc and loc[0] == "body":
        allowed = _allowed(name, kind)
    else:
        allowed = str(first.get("msg", "see the OpenAPI schema"))
    value = jsonable_encoder(first.get("input"), custom_encoder={bytes: repr})
    detail = "; ".join(f"{'.'.join(map(str, e.get('loc', ())))}: {e.get('msg')}" for e in errors)
    return {
        "detail": f"{name}={value!r} is invalid ({detail}); allowed: {allowed}",
        "error": "parameter_range" if kind != "extra_forbidden" else "unknown_parameter",
        "parameter": name,
        "value": value,
        "allowed": allowed,
    }


def _on_invalid(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    return JSONResponse(status_code=422, content=validation_problem(exc))


def _on_http(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, StarletteHTTPException)
    return JSONResponse(
        status_code=exc.status_code,
        content={"detail": str(exc.detail), "error": _HTTP_CODES.get(exc.status_code, "http")},
        headers=exc.headers,
    )


def add_error_handlers(app: FastAPI) -> None:
    """Answer the daemon's errors, validation errors and HTTP errors with problem bodies."""
    for exc_type, status, code in ERROR_STATUS:

        def handler(
            request: Request, exc: Exception, status: int = status, code: str = code
        ) -> JSONResponse:
            return JSONResponse(status_code=status, content=error_body(exc, code))

        app.add_exception_handler(exc_type, handler)
    app.add_exception_handler(RequestValidationError, _on_invalid)
    app.add_exception_handler(StarletteHTTPException, _on_http)
