"""The FastAPI application: the camera REST API under /api/v1, built around one service.

`create_app` puts the service and the options where the dependencies find them
(`elphel_camd.api.deps`), adds the body limit (`middleware`) and the error answers
(`errors`), and includes one router per resource group (`routes`). Writes (and capture,
which drives the sensor) need ``Authorization: Bearer <token>``; reads need it too when
the daemon runs read-protected. No CORS headers are sent: browsers on other origins cannot
call the API.
"""

from __future__ import annotations

from fastapi import FastAPI

from elphel_camd import __version__
from elphel_camd.api.deps import ApiOptions
from elphel_camd.api.errors import add_error_handlers
from elphel_camd.api.middleware import BodyLimit
from elphel_camd.api.routes import ROUTERS, page, param_schema
from elphel_camd.api.routes import preview as preview_routes
from elphel_camd.service import CameraService

API = "/api/v1"


def create_app(
    service: CameraService,
    *,
    token: str,
    read_protected: bool = False,
    max_body_bytes: int = 65536,
    keepalive_s: float = 15.0,
) -> FastAPI:
    """Build the API for a camera service.

    Parameters
    ----------
    service
        The camera service: the board with its detected sensors.
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
    app.state.service = service
    app.state.options = ApiOptions(
        token=token, read_protected=read_protected, keepalive_s=keepalive_s
    )
    app.add_middleware(BodyLimit, max_bytes=max_body_bytes)
    add_error_handlers(app)
    for router in ROUTERS:
        app.include_router(router, prefix=API)
    # The browser page: its API (previews, the parameter description), / and /web/.
    app.include_router(param_schema.router, prefix=API)
    app.include_router(preview_routes.router, prefix=API)
    app.include_router(page.router)
    app.mount("/web", page.static_files(), name="web")
    return app
