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
from fastapi import Depends, FastAPI, Header, HTTPException, Request
from fastapi.responses import JSONResponse, Response

from elphel_camd import __version__
from elphel_camd.board import Camera
from elphel_camd.errors import (
    CaptureUnavailableError,
    I2CError,
    ParameterRangeError,
    PortError,
    SensorNotFoundError,
)

API = "/api/v1"

_STATUS = (
    (PortError, 404),
    (SensorNotFoundError, 404),
    (ParameterRangeError, 422),
    (CaptureUnavailableError, 501),
    (I2CError, 503),
)


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

    for exc_type, status in _STATUS:

        def handler(request: Request, exc: Exception, status: int = status) -> JSONResponse:
            return JSONResponse(status_code=status, content={"detail": str(exc)})

        app.add_exception_handler(exc_type, handler)

    @app.get(f"{API}/info")
    def info() -> dict[str, Any]:
        """Board, daemon version, and each port with its detected sensor."""
        return camera.info()

    @app.post(
        f"{API}/ports/{{port}}/capture",
        dependencies=[Depends(require_token)],
        response_class=Response,
        responses={200: {"content": {"image/tiff": {}}}},
    )
    def capture(port: int) -> Response:
        """The next frame of a port as a 16-bit TIFF with JSON metadata."""
        frame, metadata = camera.capture(port)
        return Response(
            content=encode_tiff(frame.image, metadata),
            media_type="image/tiff",
            headers={"X-Frame-Number": str(frame.frame)},
        )

    return app
