"""How the API answers errors: exception -> status and code, problem bodies, 422 bodies.

Errors are JSON ``{"detail": ..., "error": ...}``; a rejected value also names
``parameter``, ``value`` and ``allowed``. A request the OpenAPI schema refuses is 422; a
request the schema allows but the port refuses — its sensor's own limits (narrower than
the schema's, which are the widest any sensor has), a window that does not fit the
sensor, a frame the schedule cannot reach, a read-only register — is 409, with the same
body. A body that is not a JSON object (not JSON, not UTF-8, a list) is 422 with
``"error": "malformed_body"`` and ``"parameter": "body"``. A missing port, sensor,
register or frame is 404, a board without an image path 501, a failing I2C bus or a
state directory that cannot be written 503 (reads keep serving), a frame that does not
come 504. Non-finite numbers in a rejected body are named as strings (``"NaN"``,
``"Infinity"``): JSON has no such numbers. Text that UTF-8 cannot carry (a lone UTF-16
surrogate such as U+D800 in a JSON body) is named with a backslash escape
(`problem`), so every error answer can be encoded. A failing I2C transfer is also logged,
once, with the request that met it: it is a fault of the board, not of the request.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Callable
from typing import Any

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from elphel_camd import errors as camd
from elphel_camd.api.models import Problem, schema_allowed
from elphel_camd.params import PARAMS

log = logging.getLogger(__name__)

# Exception type -> HTTP status and the body's "error" code; the first match wins.
ERROR_STATUS: tuple[tuple[type[Exception], int, str], ...] = (
    (camd.PortError, 404, "no_such_port"),
    (camd.SensorNotFoundError, 404, "no_sensor"),
    (camd.RegisterNotFoundError, 404, "no_such_register"),
    (camd.FrameNotAvailableError, 404, "frame_not_available"),
    (camd.ControlRefusedError, 422, "control_refused"),
    (camd.ParameterRangeError, 409, "parameter_range"),
    (camd.FrameTooLateError, 409, "frame_too_late"),
    (camd.FrameTooEarlyError, 409, "frame_too_early"),
    (camd.UnsupportedError, 409, "unsupported"),
    (camd.CaptureUnavailableError, 501, "no_image_path"),
    (camd.StateWriteError, 503, "state_not_writable"),
    (camd.I2CError, 503, "i2c"),
    (camd.PortDisconnectedError, 503, "disconnected"),
    (TimeoutError, 504, "timeout"),
)

# A body that is not a JSON object at all (not JSON, not UTF-8, a list or a string): the
# request names no parameter, so it is not a parameter's range error. Still 422.
MALFORMED_BODY = "malformed_body"
MALFORMED_BODY_KINDS = ("json_invalid", "model_attributes_type", "dict_type")

_DESCRIPTIONS = {
    401: "no or wrong bearer token",
    404: "no such port, sensor, register or frame",
    409: "allowed by the schema but refused by the port's sensor or state (its own limits, "
    "the window, the frame schedule, a read-only register); names what and why",
    413: "request body too large (names the limit)",
    422: "invalid by the schema: names the parameter, the value and what is allowed "
    "(a body that is not a JSON object: error malformed_body, parameter body); or a value "
    "a V4L2 driver refuses (error control_refused, naming the control's limits)",
    501: "the board has no image path",
    503: "the port's I2C bus fails, its video node is gone (error disconnected), or the "
    "state directory cannot be written",
    504: "the frame did not come in time",
}

_HTTP_CODES = {
    400: "bad_request",
    401: "unauthorized",
    404: "not_found",
    405: "method_not_allowed",
    421: "host_not_allowed",
}


def json_safe(value: Any) -> Any:
    """A rejected value made JSON-ready and encodable as UTF-8.

    Non-finite floats become "NaN"/"Infinity" strings; text with lone surrogates gets them
    as backslash escapes (U+D800 becomes backslash, "ud800").
    """
    if isinstance(value, float) and not math.isfinite(value):
        return "NaN" if math.isnan(value) else ("Infinity" if value > 0 else "-Infinity")
    if isinstance(value, str):
        return value.encode("utf-8", "backslashreplace").decode("utf-8")
    if isinstance(value, dict):
        return {json_safe(str(k)): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


def problem(
    status: int, body: dict[str, Any], headers: dict[str, str] | None = None
) -> JSONResponse:
    """An error answer: ``body`` made encodable (`json_safe`) whatever text it names."""
    return JSONResponse(status_code=status, content=json_safe(body), headers=headers)


def error_responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    """The OpenAPI ``responses`` entries of a route's error statuses."""
    return {code: {"model": Problem, "description": _DESCRIPTIONS[code]} for code in codes}


def error_body(exc: Exception, code: str) -> dict[str, Any]:
    """The problem body of a daemon error."""
    body: dict[str, Any] = {"detail": str(exc), "error": code}
    if isinstance(exc, camd.ParameterRangeError):
        body.update(
            parameter=exc.name, value=json_safe(jsonable_encoder(exc.value)), allowed=exc.allowed
        )
    elif isinstance(exc, camd.I2CError):
        body.update(bus=exc.bus, address=exc.address, register=exc.register)
        if isinstance(exc, camd.PortI2CError):
            body["port"] = exc.port
    elif isinstance(exc, camd.FrameScheduleError):
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
        return schema_allowed(spec)
    return "see the OpenAPI schema"


def validation_problem(
    exc: RequestValidationError, narrower: Callable[[str], str | None] = lambda name: None
) -> dict[str, Any]:
    """A 422 body in the API's own form from FastAPI's validation errors.

    ``narrower(name)`` gives the range the port's sensor allows, when narrower than the
    schema's (`sensor_allowed`).
    """
    errors = list(exc.errors())
    first = errors[0] if errors else {"loc": ("body",), "msg": "invalid", "type": "invalid"}
    loc = [str(part) for part in first.get("loc", ())]
    name = loc[-1] if len(loc) > 1 else (loc[0] if loc else "body")
    kind = str(first.get("type", ""))
    detail = "; ".join(f"{'.'.join(map(str, e.get('loc', ())))}: {e.get('msg')}" for e in errors)
    if name == "body" or kind in MALFORMED_BODY_KINDS:
        # not JSON: pydantic's input is a placeholder, not what was sent
        sent = None if kind == "json_invalid" else first.get("input")
        return {
            "detail": f"the request body is not a JSON object ({detail}); allowed: a JSON object",
            "error": MALFORMED_BODY,
            "parameter": "body",
            "value": json_safe(jsonable_encoder(sent, custom_encoder={bytes: repr})),
            "allowed": "a JSON object",
        }
    if loc and loc[0] == "body":
        allowed = _allowed(name, kind)
        if kind != "extra_forbidden":
            allowed = narrower(name) or allowed
    else:
        allowed = str(first.get("msg", "see the OpenAPI schema"))
    value = json_safe(jsonable_encoder(first.get("input"), custom_encoder={bytes: repr}))
    given = first.get("input")
    if isinstance(given, float) and not math.isfinite(given):
        allowed = f"a finite number: {allowed}"
    return {
        "detail": f"{name}={value!r} is invalid ({detail}); allowed: {allowed}",
        "error": "unknown_parameter" if kind == "extra_forbidden" else "parameter_range",
        "parameter": name,
        "value": value,
        "allowed": allowed,
    }


def sensor_allowed(request: Request, name: str) -> str | None:
    """What the sensor on the request's port allows for ``name`` (None: nothing narrower).

    The schema's fixed limits are the widest any sensor takes; the range a user can act
    on is the sensor's, as its driver names it when refusing the schema's maximum.
    """
    spec = PARAMS.get(name)
    port = request.path_params.get("port")
    service = getattr(request.app.state, "service", None)
    if spec is None or spec.read_only or port is None or service is None:
        return None
    try:
        driver = service.sensor(int(port))
        state = service.params(int(port))
        driver.normalize({**state, name: spec.maximum}, frozenset({name}))
    except camd.ParameterRangeError as e:
        return e.allowed if e.name == name else None
    except (camd.CameraError, ValueError, KeyError):
        return None
    return None


def _on_invalid(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    return problem(422, validation_problem(exc, lambda name: sensor_allowed(request, name)))


def allowed_methods(request: Request) -> list[str]:
    """Every method the API's schema declares on the request's path (for ``Allow``)."""
    methods: set[str] = set()
    for template, item in request.app.openapi().get("paths", {}).items():
        pattern = re.sub(r"\\\{[^/]+?\\\}", "[^/]+", re.escape(template))
        if re.fullmatch(pattern, request.url.path):
            methods.update(m.upper() for m in item)
    if "GET" in methods:
        methods.add("HEAD")
    return sorted(methods)


def _on_http(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, StarletteHTTPException)
    if exc.status_code == 400 and request.method in ("PATCH", "PUT", "POST"):
        # FastAPI's answer to a body it cannot decode (not UTF-8): invalid input, like
        # a body that is not JSON.
        return problem(
            422,
            {
                "detail": f"the request body cannot be read: {exc.detail}",
                "error": MALFORMED_BODY,
                "parameter": "body",
                "value": None,
                "allowed": "a JSON object (UTF-8)",
            },
        )
    headers = dict(exc.headers or {})
    if exc.status_code == 405:
        # Starlette names the methods of the first route that matched the path only; a
        # path served by several routes (GET and PATCH of params) has all of theirs.
        headers["Allow"] = ", ".join(allowed_methods(request))
    return problem(
        exc.status_code,
        {"detail": str(exc.detail), "error": _HTTP_CODES.get(exc.status_code, "http")},
        headers,
    )


def add_error_handlers(app: FastAPI) -> None:
    """Answer the daemon's errors, validation errors and HTTP errors with problem bodies."""
    for exc_type, status, code in ERROR_STATUS:

        def handler(
            request: Request, exc: Exception, status: int = status, code: str = code
        ) -> JSONResponse:
            if isinstance(exc, camd.I2CError):
                log.warning("%s %s: %s", request.method, request.url.path, exc)
            return problem(status, error_body(exc, code))

        app.add_exception_handler(exc_type, handler)
    app.add_exception_handler(RequestValidationError, _on_invalid)
    app.add_exception_handler(StarletteHTTPException, _on_http)
