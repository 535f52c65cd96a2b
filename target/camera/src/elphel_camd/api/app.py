"""FastAPI application: the camera REST API under /api/v1 (shared/DESIGN.md section 4.2).

Writes (and capture, which drives the sensor) need ``Authorization: Bearer <token>``;
reads need it too when the daemon runs read-protected. Errors are JSON
``{"detail": ..., "error": ...}``, and a rejected value also names ``parameter``,
``value`` and ``allowed``: invalid input is 422, a missing port, sensor or frame 404, a
board without an image path 501, a failing I2C bus 503 (other ports keep serving), a
frame that does not come 504. No CORS headers are sent: browsers on other origins cannot
call the API.
"""

from __future__ import annotations

import json
import logging
import secrets
from collections.abc import AsyncIterator, Iterator
from typing import Annotated, Any

from fastapi import Depends, FastAPI, Path, Query, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, StreamingResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from elphel_camd import __version__
from elphel_camd.api import tiff
from elphel_camd.api.models import (
    FrameInfo,
    Health,
    Info,
    Params,
    ParamsPatch,
    PatchResult,
    Problem,
    RegisterEntry,
    RegisterValue,
    RegisterWrite,
)
from elphel_camd.board import Camera
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
from elphel_camd.events import EVENT_TYPES
from elphel_camd.params import PARAMS
from elphel_camd.sensors import register_file
from elphel_camd.sensors.registers import Register

API = "/api/v1"
log = logging.getLogger(__name__)

_STATUS: tuple[tuple[type[Exception], int, str], ...] = (
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


def _errors(*codes: int) -> dict[int | str, dict[str, Any]]:
    return {code: {"model": Problem, "description": _DESCRIPTIONS[code]} for code in codes}


def _error_body(exc: Exception, code: str) -> dict[str, Any]:
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


def parse_frame(frame: str | None, ahead: int | None) -> tuple[int | None, int | None]:
    """``frame=N`` (absolute) or ``frame=+k`` / ``ahead=k`` (relative) from a query."""
    if frame is not None and ahead is not None:
        raise UnsupportedError("give frame or ahead, not both")
    if frame is None:
        return None, ahead
    text = frame.strip()
    try:
        value = int(text)
    except ValueError:
        raise ParameterRangeError("frame", frame, "N (absolute) or +k (relative)") from None
    if text.startswith("+"):
        return None, value
    return value, None


def parse_address(text: str) -> int:
    try:
        return int(text, 0)
    except ValueError:
        raise ParameterRangeError("address", text, "a register address, e.g. 0x09 or 9") from None


def encode_tiff(image: Any, metadata: dict[str, Any]) -> bytes:
    """A one-page 16-bit TIFF whose ImageDescription is the JSON metadata."""
    return tiff.encode(image, {"shape": list(image.shape), **metadata})


# Module level: the routes' annotations are strings resolved in this module's namespace.
Frame = Annotated[int | None, Query(ge=0, le=0x7FFFFFFF, description="frame number")]
Port = Annotated[int, Path(ge=0, le=0x7FFFFFFF, description="sensor port (0..3 on NC393)")]
Address = Annotated[
    str,
    Path(
        pattern=r"^(0[xX][0-9a-fA-F]{1,4}|[0-9]{1,5})$",
        description="register address, decimal or 0x hex",
    ),
]
_BEARER = Depends(HTTPBearer(auto_error=False, description="the daemon's token"))


class BodyLimit:
    """Answer 413 to request bodies over ``max_bytes`` (declared or actually sent)."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def _reject(self, send: Send) -> None:
        body = json.dumps(
            {"detail": f"request body over {self.max_bytes} bytes", "error": "too_large"}
        ).encode()
        await send(
            {
                "type": "http.response.start",
                "status": 413,
                "headers": [(b"content-type", b"application/json")],
            }
        )
        await send({"type": "http.response.body", "body": body})

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for key, value in scope["headers"]:
            if key == b"content-length" and value.isdigit() and int(value) > self.max_bytes:
                await self._reject(send)
                return
        received = 0
        started = False

        async def counted() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    raise _BodyTooLargeError
            return message

        async def tracked(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, counted, tracked)
        except _BodyTooLargeError:
            if not started:
                await self._reject(send)


class _BodyTooLargeError(Exception):
    pass


def create_app(
    camera: Camera,
    *,
    token: str,
    read_protected: bool = False,
    max_body_bytes: int = 65536,
    keepalive_s: float = 15.0,
) -> FastAPI:
    """Build the API for a camera.

    Parameters
    ----------
    camera
        The board with its detected sensors.
    token
        The bearer token that write requests (and reads, if read-protected) must carry.
    read_protected
        Reads need the token too (the health check excepted).
    max_body_bytes
        Largest request body; larger ones get 413.
    keepalive_s
        Idle time after which the event stream sends a comment line.
    """
    if not token:
        raise ValueError("the API token must not be empty")
    app = FastAPI(
        title="elphel-camd",
        version=__version__,
        description="Camera daemon of an Elphel-style board: frame parameters, capture, "
        "raw registers and events. Parameter names and units follow Elphel's.",
    )
    app.add_middleware(BodyLimit, max_bytes=max_body_bytes)
    expected = token.encode()

    async def require_token(credentials: HTTPAuthorizationCredentials | None = _BEARER) -> None:
        if credentials is None or not secrets.compare_digest(
            credentials.credentials.encode(), expected
        ):
            raise StarletteHTTPException(
                status_code=401,
                detail="this request needs the camera's token: send Authorization: Bearer <token>",
                headers={"WWW-Authenticate": "Bearer"},
            )

    async def require_read(credentials: HTTPAuthorizationCredentials | None = _BEARER) -> None:
        if read_protected:
            await require_token(credentials)

    writes = [Depends(require_token)]
    reads = [Depends(require_read)]

    for exc_type, status, code in _STATUS:

        def handler(
            request: Request, exc: Exception, status: int = status, code: str = code
        ) -> JSONResponse:
            return JSONResponse(status_code=status, content=_error_body(exc, code))

        app.add_exception_handler(exc_type, handler)

    def on_invalid(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, RequestValidationError)
        return JSONResponse(status_code=422, content=validation_problem(exc))

    def on_http(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, StarletteHTTPException)
        code = {401: "unauthorized", 404: "not_found", 405: "method_not_allowed"}
        return JSONResponse(
            status_code=exc.status_code,
            content={"detail": str(exc.detail), "error": code.get(exc.status_code, "http")},
            headers=exc.headers,
        )

    app.add_exception_handler(RequestValidationError, on_invalid)
    app.add_exception_handler(StarletteHTTPException, on_http)

    # -- board -----------------------------------------------------------------------------

    @app.get(f"{API}/info", response_model=Info, dependencies=reads, responses=_errors(401, 503))
    def info() -> JSONResponse:
        """Board, daemon version, and each port with its detected sensor."""
        return JSONResponse(camera.info())

    @app.get(
        f"{API}/health",
        response_model=Health,
        responses={503: {"model": Health, "description": "a port's I2C bus fails"}},
    )
    def health() -> JSONResponse:
        """Each sensor answering on its bus now; 503 (status degraded) if one does not."""
        report = camera.health()
        return JSONResponse(report, status_code=200 if report["status"] == "ok" else 503)

    # -- parameters ------------------------------------------------------------------------

    @app.get(
        f"{API}/ports/{{port}}/params",
        response_model=Params,
        dependencies=reads,
        responses=_errors(401, 404, 422, 503),
    )
    def get_params(port: Port, frame: Frame = None) -> JSONResponse:
        """Parameters in effect now, or for a recent or scheduled frame."""
        return JSONResponse(camera.params(port, frame=frame))

    @app.patch(
        f"{API}/ports/{{port}}/params",
        response_model=PatchResult,
        dependencies=writes,
        responses=_errors(401, 404, 413, 422, 503),
    )
    def patch_params(
        port: Port,
        changes: ParamsPatch,  # type: ignore[valid-type]
        frame: Annotated[
            str | None,
            Query(
                pattern=r"^\s*\+?[0-9]{1,10}\s*$",
                description="target frame: N (absolute) or +k (k frames ahead)",
            ),
        ] = None,
        ahead: Annotated[
            int | None, Query(ge=0, le=0x7FFFFFFF, description="same as frame=+k")
        ] = None,
    ) -> JSONResponse:
        """Set parameters (all or none), now or at a frame; answers the frame they take effect."""
        absolute, relative = parse_frame(frame, ahead)
        values = changes.model_dump(exclude_unset=True)  # type: ignore[attr-defined]
        target = camera.set_params(port, values, frame=absolute, ahead=relative)
        params = camera.params(port, frame=target) if camera.scheduled else camera.params(port)
        return JSONResponse({"frame": target, "params": params})

    @app.get(
        f"{API}/ports/{{port}}/frame",
        response_model=FrameInfo,
        dependencies=reads,
        responses=_errors(401, 404),
    )
    def get_frame(port: Port) -> JSONResponse:
        """The current frame number of a port and when it started."""
        seq = camera.sequencer(port)
        return JSONResponse(
            {"port": port, "frame": seq.this_frame, "timestamp_ns": seq.this_timestamp_ns}
        )

    # -- capture ---------------------------------------------------------------------------

    tiff_content = {"image/tiff": {"schema": {"type": "string", "format": "binary"}}}

    @app.post(
        f"{API}/ports/{{port}}/capture",
        dependencies=writes,
        response_class=StreamingResponse,
        responses={
            200: {"content": tiff_content, "description": "16-bit TIFF, one page per frame"},
            **_errors(401, 404, 422, 501, 503, 504),
        },
    )
    def capture(
        port: Port,
        frame: Frame = None,
        count: Annotated[int, Query(ge=1, le=1024, description="consecutive frames")] = 1,
    ) -> StreamingResponse:
        """The next frame (or recent frame ``frame``) as a 16-bit TIFF with its metadata.

        With ``count=N``, N consecutive frames from there as a multi-page TIFF, sent page
        by page as the frames come. Each page's ImageDescription is that frame's JSON
        metadata; the first frame's number is in ``X-Frame-Number``.
        """
        frames = camera.burst(port, count, frame=frame)
        first, metadata = next(frames)  # errors before the answer starts get their status
        headers = {"X-Frame-Number": str(first.frame), "X-Frame-Count": str(count)}
        if count == 1:
            # Known length: no chunked encoding, and the pixels go out without a copy.
            chunks, length = tiff.single(
                first.image, {"shape": list(first.image.shape), **metadata}
            )

            async def one_page() -> AsyncIterator[bytes | memoryview]:
                for chunk in chunks:
                    yield chunk

            return StreamingResponse(
                one_page(),
                media_type="image/tiff",
                headers={**headers, "Content-Length": str(length)},
            )

        def pages() -> Iterator[tuple[Any, dict[str, Any]]]:
            yield first.image, metadata
            try:
                for got, meta in frames:
                    yield got.image, meta
            except Exception as e:
                # The status is sent already: end the stream short; the client sees fewer
                # pages than X-Frame-Count.
                log.error("port %d: burst ended early: %s", port, e)

        return StreamingResponse(
            tiff.stream(pages(), count), media_type="image/tiff", headers=headers
        )

    # -- raw registers ---------------------------------------------------------------------

    def register_body(port: int, register: Register, value: int) -> dict[str, Any]:
        return {
            "port": port,
            "name": register.name,
            "address": register.address,
            "value": value,
            "access": str(register.access),
            "minimum": register.minimum,
            "maximum": register.limit,
            "unit": register.unit,
            "doc": register.doc,
        }

    @app.get(
        f"{API}/ports/{{port}}/registers",
        response_model=list[RegisterEntry],
        dependencies=reads,
        responses=_errors(401, 404, 422),
    )
    def list_registers(port: Port) -> JSONResponse:
        """The sensor's register table: names, addresses, access, reset values, limits."""
        table = register_file(camera.sensor(port)).table
        return JSONResponse(
            [
                {
                    "name": r.name,
                    "address": r.address,
                    "access": str(r.access),
                    "reset": r.reset,
                    "minimum": r.minimum,
                    "maximum": r.limit,
                    "width": r.width,
                    "unit": r.unit,
                    "doc": r.doc,
                }
                for r in table
            ]
        )

    @app.get(
        f"{API}/ports/{{port}}/registers/{{addr}}",
        response_model=RegisterValue,
        dependencies=reads,
        responses=_errors(401, 404, 422, 503),
    )
    def get_register(port: Port, addr: Address) -> JSONResponse:
        """Read a raw sensor register now (address decimal or 0x hex)."""
        register, value = camera.read_register(port, parse_address(addr))
        return JSONResponse(register_body(port, register, value))

    @app.put(
        f"{API}/ports/{{port}}/registers/{{addr}}",
        response_model=RegisterValue,
        dependencies=writes,
        responses=_errors(401, 404, 413, 422, 503),
    )
    def put_register(port: Port, addr: Address, body: RegisterWrite) -> JSONResponse:
        """Write a raw sensor register (admin), checked against the register table.

        The write bypasses the frame sequencer: the next change of a parameter that owns
        this register overwrites it.
        """
        register = camera.write_register(port, parse_address(addr), body.value)
        return JSONResponse(register_body(port, register, body.value))

    # -- events ----------------------------------------------------------------------------

    @app.get(
        f"{API}/events",
        dependencies=reads,
        response_class=StreamingResponse,
        responses={
            200: {
                "content": {"text/event-stream": {"schema": {"type": "string"}}},
                "description": "server-sent events: frame, params, error (and dropped)",
            },
            **_errors(401, 422),
        },
    )
    async def events(
        types: Annotated[
            str,
            Query(
                pattern=r"^(frame|params|error)(,(frame|params|error))*$",
                description="comma-separated event types",
            ),
        ] = ",".join(EVENT_TYPES),
        port: Annotated[int | None, Query(description="only this port's events")] = None,
        count: Annotated[
            int | None, Query(ge=1, le=1_000_000, description="end after this many events")
        ] = None,
    ) -> StreamingResponse:
        """Server-sent events: ``frame``, ``params`` and ``error``, each a JSON ``data`` line.

        A client that falls more than the queue size behind loses the oldest events and
        gets a ``dropped`` event with the running count; acquisition never waits for it.
        """
        sub = camera.events.subscribe(types.split(","), port=port)

        async def stream() -> AsyncIterator[str]:
            try:
                yield "retry: 2000\n\n"
                sent = reported = 0
                while count is None or sent < count:
                    event = await sub.get(keepalive_s)
                    if sub.dropped > reported:
                        reported = sub.dropped
                        yield f"event: dropped\ndata: {json.dumps({'dropped': reported})}\n\n"
                    if event is None:
                        yield ": keepalive\n\n"
                        continue
                    data = json.dumps(event.data, separators=(",", ":"))
                    yield f"id: {event.id}\nevent: {event.type}\ndata: {data}\n\n"
                    sent += 1
            finally:
                camera.events.unsubscribe(sub)

        return StreamingResponse(
            stream(),
            media_type="text/event-stream",
            headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
        )

    return app
