"""The FastAPI application: the camera REST API under /api/v1, built around one service.

`create_app` puts the service and the options where the dependencies find them
(`elphel_camd.api.deps`), adds the body limit, the Host allow-list and the security
headers (`middleware`), CORS only for the origins it is given, and the error answers
(`errors`), and includes one router per resource group (`routes`). Every request but
``GET /health`` needs ``Authorization: Bearer <token>`` unless the app is built with
``public_reads``, which opens the reads (writes and capture still need it). The OpenAPI
schema says exactly that: its ``security`` is what the daemon checks. ``/docs`` is a
small self-contained page (no assets from a CDN, so it works on an offline camera) that
lists the operations from ``/openapi.json``.
"""

from __future__ import annotations

import base64
import hashlib
import html
from collections.abc import Sequence
from typing import Any

from fastapi import FastAPI, Request
from fastapi.middleware.cors import CORSMiddleware
from fastapi.openapi.utils import get_openapi
from fastapi.responses import HTMLResponse

from elphel_camd import __version__
from elphel_camd.api.deps import ApiOptions, TokenSource
from elphel_camd.api.errors import add_error_handlers
from elphel_camd.api.fast_path import ParamsFastPath
from elphel_camd.api.middleware import BodyLimit, HostAllowList, SecurityHeaders
from elphel_camd.api.models import EVENT_SCHEMA, Problem
from elphel_camd.api.routes import ROUTERS, page, param_schema
from elphel_camd.api.routes import preview as preview_routes
from elphel_camd.service import CameraService

API = "/api/v1"

# Operations that are reads (guarded by READS): their security depends on public_reads.
_READ_METHODS = ("get", "head")
_PROBLEM_REF = {"$ref": "#/components/schemas/Problem"}


def create_app(
    service: CameraService,
    *,
    token: str | TokenSource,
    public_reads: bool = False,
    max_body_bytes: int = 65536,
    keepalive_s: float = 15.0,
    stream_idle_s: float = 300.0,
    allowed_hosts: Sequence[str] | None = None,
    cors_origins: Sequence[str] = (),
    fast_path: bool = True,
) -> FastAPI:
    """Build the API for a camera service.

    Parameters
    ----------
    service
        The camera service: the board with its detected sensors.
    token
        The bearer token (or its `TokenSource`, e.g. the token file, re-read when it
        changes) that requests must carry.
    public_reads
        Answer reads without the token (the health check never needs it).
    max_body_bytes
        Largest request body; larger ones get 413.
    keepalive_s
        Idle time after which the event stream sends a comment line.
    stream_idle_s
        An event stream with no event of its types for this long ends.
    allowed_hosts
        Host names (besides IP addresses and ``localhost``) the ``Host`` header may
        carry; None checks nothing (in-process clients), ``["*"]`` allows any.
    cors_origins
        Origins whose browser pages may call the API (CORS); none by default.
    fast_path
        Answer plain GET/PATCH of a port's params without FastAPI's per-request work
        (`elphel_camd.api.fast_path`; the same answers). False only to compare.
    """
    source = token if isinstance(token, TokenSource) else TokenSource(token)
    app = FastAPI(
        title="elphel-camd",
        version=__version__,
        description="Camera daemon of an Elphel-style board: frame parameters, capture, "
        "raw registers and events. Parameter names and units follow Elphel's. Every "
        "request but GET /health needs the bearer token"
        + (" (reads are public on this daemon)." if public_reads else ".")
        + " A value the schema allows can still be refused by the port's sensor or state "
        "(409, naming the parameter and its allowed range).",
        docs_url=None,
        redoc_url=None,
    )
    app.state.service = service
    app.state.options = ApiOptions(
        token=source,
        public_reads=public_reads,
        keepalive_s=keepalive_s,
        stream_idle_s=stream_idle_s,
    )
    if fast_path:
        app.add_middleware(ParamsFastPath)  # added first: the innermost, under every limit
    app.add_middleware(BodyLimit, max_bytes=max_body_bytes)
    if cors_origins:
        add_cors(app, cors_origins)
    if allowed_hosts is not None:
        app.add_middleware(HostAllowList, allowed=allowed_hosts)
    app.add_middleware(SecurityHeaders)  # the outermost: on every answer, refusals included
    add_error_handlers(app)
    include_routes(app)
    serve_contract(app, public_reads=public_reads)
    return app


def add_cors(app: FastAPI, origins: Sequence[str]) -> None:
    """Let browser pages of ``origins`` call the API (and read the frame headers)."""
    app.add_middleware(
        CORSMiddleware,
        allow_origins=list(origins),
        allow_methods=["GET", "PATCH", "PUT", "POST"],
        allow_headers=["Authorization", "Content-Type", "Last-Event-ID"],
        expose_headers=["X-Frame-Number", "X-Frame-Count"],
    )


def include_routes(app: FastAPI) -> None:
    """The API's routers under `API`, then the browser page: its API, / and /web/."""
    for router in ROUTERS:
        app.include_router(router, prefix=API)
    app.include_router(param_schema.router, prefix=API)
    app.include_router(preview_routes.router, prefix=API)
    app.include_router(page.router)
    app.mount("/web", page.static_files(), name="web")


def serve_contract(app: FastAPI, *, public_reads: bool) -> None:
    """Make ``app.openapi()`` the `contract` schema, and ``/docs`` the page that lists it."""

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            schema = get_openapi(
                title=app.title,
                version=app.version,
                description=app.description,
                routes=app.routes,
            )
            app.openapi_schema = contract(schema, public_reads=public_reads)
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]
    app.add_api_route("/docs", docs, methods=["GET"], include_in_schema=False)


def docs(request: Request) -> HTMLResponse:
    """``GET /docs``: the page that lists the app's contract.

    One function for every app, reaching its app through the request: FastAPI keeps the
    endpoints it has seen in a process-wide cache, and an endpoint that closed over its
    app would keep the app, its camera service and the board alive for good.
    """
    schema = request.app.openapi()
    return HTMLResponse(docs_page(schema), headers={"Content-Security-Policy": DOCS_CSP})


def contract(schema: dict[str, Any], *, public_reads: bool) -> dict[str, Any]:
    """Make the generated schema say what the daemon does.

    Reads declare the bearer security unless they are public (then they never answer
    401); the event stream declares each event it sends.
    """
    schema.setdefault("components", {}).setdefault("schemas", {})
    schema["components"]["schemas"].setdefault("Problem", Problem.model_json_schema())
    invalid = {
        "description": "invalid by the schema: names the parameter, the value and what is allowed",
        "content": {"application/json": {"schema": _PROBLEM_REF}},
    }
    for path, item in schema.get("paths", {}).items():
        for method, operation in item.items():
            responses = operation.setdefault("responses", {})
            if operation.get("parameters") or operation.get("requestBody"):
                responses["422"] = invalid  # the API's problem body, not FastAPI's own
            if public_reads and method in _READ_METHODS:
                operation.pop("security", None)
                responses.pop("401", None)
            if path == f"{API}/events" and method == "get":
                ok = responses.get("200", {}).get("content", {}).get("text/event-stream")
                if ok is not None:
                    ok["schema"] = EVENT_SCHEMA
    schemas = schema["components"]["schemas"]
    if not any(
        "HTTPValidationError" in str(op)
        for item in schema["paths"].values()
        for op in item.values()
    ):
        schemas.pop("HTTPValidationError", None)
        schemas.pop("ValidationError", None)
    return schema


# The /docs page's one inline style, allowed by its hash: nothing else runs or loads there.
DOCS_STYLE = (
    "body{font-family:sans-serif;margin:2em}td{padding:2px 8px;border-bottom:1px solid #ddd}"
)
DOCS_CSP = (
    "default-src 'none'; style-src "
    f"'sha256-{base64.b64encode(hashlib.sha256(DOCS_STYLE.encode()).digest()).decode()}'; "
    "base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
)


def docs_page(schema: dict[str, Any]) -> str:
    """A self-contained HTML page listing the API's operations (no external assets)."""
    rows = []
    for path, item in schema.get("paths", {}).items():
        for method, operation in item.items():
            codes = ", ".join(sorted(operation.get("responses", {})))
            summary = operation.get("summary") or operation.get("operationId", "")
            lock = "" if "security" not in operation else " &#128274;"
            rows.append(
                f"<tr><td><code>{method.upper()}</code></td><td><code>{html.escape(path)}"
                f"</code>{lock}</td><td>{html.escape(str(summary))}</td><td>{codes}</td></tr>"
            )
    title = html.escape(f"{schema['info']['title']} {schema['info']['version']}")
    return (
        "<!doctype html><html><head><meta charset='utf-8'>"
        f"<title>{title}</title><style>{DOCS_STYLE}</style></head><body>"
        f"<h1>{title}</h1><p>{html.escape(schema['info'].get('description', ''))}</p>"
        "<p>The full schema: <a href='/openapi.json'>/openapi.json</a> (&#128274; = needs "
        "the bearer token).</p><table><tr><th>method</th><th>path</th><th>what</th>"
        f"<th>answers</th></tr>{''.join(rows)}</table></body></html>"
    )
