"""What the routes are given: the camera service, the API options, the bearer-token checks.

`create_app` puts the service on ``app.state.service`` and the `ApiOptions` on
``app.state.options``; the routes receive them through FastAPI dependencies (`Service`,
`Options`) and are guarded by `WRITES` (the token) or `READS` (the token only when the
daemon is read-protected). `PortPath` and `FrameQuery` are the path and query parameters
the port routes share.
"""

from __future__ import annotations

import secrets
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, Path, Query, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.exceptions import HTTPException as StarletteHTTPException

from elphel_camd.service import CameraService


@dataclass(frozen=True)
class ApiOptions:
    """How the API guards and streams (fixed when the app is built).

    Parameters
    ----------
    token
        The bearer token that writes (and reads, if read-protected) must carry.
    read_protected
        Reads need the token too (the health check excepted).
    keepalive_s
        Idle time after which the event stream sends a comment line.
    """

    token: str
    read_protected: bool = False
    keepalive_s: float = 15.0


async def get_service(request: Request) -> CameraService:
    """The camera service the app was built for."""
    service: CameraService = request.app.state.service
    return service


async def get_options(request: Request) -> ApiOptions:
    """The options the app was built with."""
    options: ApiOptions = request.app.state.options
    return options


Service = Annotated[CameraService, Depends(get_service)]
Options = Annotated[ApiOptions, Depends(get_options)]

_BEARER = Depends(HTTPBearer(auto_error=False, description="the daemon's token"))


async def require_token(
    options: Options, credentials: HTTPAuthorizationCredentials | None = _BEARER
) -> None:
    """401 unless the request carries the daemon's bearer token."""
    if credentials is None or not secrets.compare_digest(
        credentials.credentials.encode(), options.token.encode()
    ):
        raise StarletteHTTPException(
            status_code=401,
            detail="this request needs the camera's token: send Authorization: Bearer <token>",
            headers={"WWW-Authenticate": "Bearer"},
        )


async def require_read(
    options: Options, credentials: HTTPAuthorizationCredentials | None = _BEARER
) -> None:
    """The token check, for reads of a read-protected daemon only."""
    if options.read_protected:
        await require_token(options, credentials)


WRITES = [Depends(require_token)]
READS = [Depends(require_read)]

PortPath = Annotated[int, Path(ge=0, le=0x7FFFFFFF, description="sensor port (0..3 on NC393)")]
FrameQuery = Annotated[int | None, Query(ge=0, le=0x7FFFFFFF, description="frame number")]
