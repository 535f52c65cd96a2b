"""FastAPI application: the camera REST API under /api/v1 (shared/DESIGN.md section 4.2).

Reads are open; writes (and capture, which drives the sensor) need
``Authorization: Bearer <token>``. Errors are JSON ``{"detail": ...}``; invalid input is
422, a missing port or sensor 404, a board without an image path 501, a failing I2C bus 503.
"""

from __future__ import annotations

import io
import secrets
from typing import Annotated, Any

import tifffile
from fastapi import Body, Depends, FastAPI, Header, HTTPException, Request
from fastapi.responses import JSONResponse, Response

from elphel_camd import __version__
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

API = "/api/v1"

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
)


def _error_body(exc: Exception, code: str) -> dict[str, Any]:
    body: dict[str, Any] = {"detail": str(exc), "error": code}
    if isinstance(exc, ParameterRangeError):
        body.update(parameter=exc.name, value=exc.value, allowed=exc.allowed)
    elif isinstance(exc, FrameScheduleError):
        body.update(
            frame=exc.frame, this_frame=exc.this_frame, earliest=exc.earliest, latest=exc.latest
        )
    return body


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


def encode_tiff(image: Any, metadata: dict[str, Any]) -> bytes:
    """A 16-bit TIFF whose ImageDescription is the JSON metadata (tifffile's ``metadata=``)."""
    buffer = io.BytesIO()
    tifffile.imwrite(buffer, image, photometric="minisblack", metadata=metadata)
    return buffer.getvalue()


def create_app(camera: Camera, *, token: str) -> FastAPI:
    """Build the API for a camera.

    Parameters
    ----------
    camera
        The board with its detected sensors.
    token
        The bearer token that write requests must carry.
    """
    if not token:
        raise ValueError("the API token must not be empty")
    app = FastAPI(title="elphel-camd", version=__version__)
    expected = f"Bearer {token}".encode()

    def require_token(authorization: Annotated[str | None, Header()] = None) -> None:
        if authorization is None or not secrets.compare_digest(authorization.encode(), expected):
            raise HTTPException(
                status_code=401,
                detail="this request changes the camera: send Authorization: Bearer <token>",
                headers={"WWW-Authenticate": "Bearer"},
            )

    for exc_type, status, code in _STATUS:

        def handler(
            request: Request, exc: Exception, status: int = status, code: str = code
        ) -> JSONResponse:
            return JSONResponse(status_code=status, content=_error_body(exc, code))

        app.add_exception_handler(exc_type, handler)

    @app.get(f"{API}/info")
    def info() -> dict[str, Any]:
        """Board, daemon version, and each port with its detected sensor."""
        return camera.info()

    @app.get(f"{API}/ports/{{port}}/params")
    def get_params(port: int, frame: int | None = None) -> dict[str, Any]:
        """Parameters in effect now, or for a recent or scheduled frame."""
        return camera.params(port, frame=frame)

    @app.patch(f"{API}/ports/{{port}}/params", dependencies=[Depends(require_token)])
    def patch_params(
        port: int,
        changes: Annotated[dict[str, int], Body()],
        frame: str | None = None,
        ahead: int | None = None,
    ) -> dict[str, Any]:
        """Set parameters (all or none), now or at a frame; answers the frame they take effect."""
        absolute, relative = parse_frame(frame, ahead)
        target = camera.set_params(port, changes, frame=absolute, ahead=relative)
        params = camera.params(port, frame=target) if camera.scheduled else camera.params(port)
        return {"frame": target, "params": params}

    @app.get(f"{API}/ports/{{port}}/frame")
    def get_frame(port: int) -> dict[str, Any]:
        """The current frame number of a port and when it started."""
        seq = camera.sequencer(port)
        return {"port": port, "frame": seq.this_frame, "timestamp_ns": seq.this_timestamp_ns}

    @app.post(
        f"{API}/ports/{{port}}/capture",
        dependencies=[Depends(require_token)],
        response_class=Response,
        responses={200: {"content": {"image/tiff": {}}}},
    )
    def capture(port: int, frame: int | None = None) -> Response:
        """The next frame of a port (or recent frame ``frame``) as a 16-bit TIFF with metadata."""
        got, metadata = camera.capture(port, frame=frame)
        return Response(
            content=encode_tiff(got.image, metadata),
            media_type="image/tiff",
            headers={"X-Frame-Number": str(got.frame)},
        )

    return app
