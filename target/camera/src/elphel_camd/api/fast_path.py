"""The two busiest requests answered without FastAPI's per-request machinery.

``GET`` and ``PATCH /api/v1/ports/{port}/params`` are most of what scripts send. For each
request FastAPI resolves the route's dependencies, reads the query and headers into
parameters and wraps the call in its exception and exit-stack layers, work that costs
more than reading or scheduling a few parameters. `ParamsFastPath` answers the plain
form of the two (no query string; the bearer token right by `deps.token_accepted`, or
reads public; for PATCH a JSON body that `ParamsPatch` accepts) by calling the functions
the routes call (`read_params`, `write_params`), and the app's own exception handlers for
their errors. Anything else goes on to the routes, which answer as they always do, the
body handed on as it was read: a query (``frame``, ``ahead``), a missing or wrong token
(the routes log it and slow the peer down), a port the board does not have, a body the
model refuses (the routes' 422). The routes stay what the OpenAPI schema describes; this
changes no answer, only what computes it.
"""

from __future__ import annotations

import inspect
import json
import re
from collections.abc import Coroutine
from typing import Any

from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from elphel_camd.api.deps import ApiOptions, token_accepted
from elphel_camd.api.models import ParamsPatch
from elphel_camd.api.routes.params import read_params, write_params
from elphel_camd.service import CameraService

_PATH = re.compile(r"/api/v1/ports/([0-9]{1,9})/params")


class ParamsFastPath:
    """ASGI middleware: plain GET/PATCH of a port's params, straight to the service."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        method = scope.get("method")
        match = None
        if scope["type"] == "http" and method in ("GET", "PATCH") and not scope["query_string"]:
            match = _PATH.fullmatch(scope["path"])
        if match is None:
            await self.app(scope, receive, send)
            return
        api = scope["app"]
        service: CameraService = api.state.service
        options: ApiOptions = api.state.options
        port = int(match[1])
        headers = dict(scope["headers"])
        needs_token = method == "PATCH" or not options.public_reads
        allowed = not needs_token or _has_token(scope, options)
        if port not in service.sequencers or not allowed:
            await self.app(scope, receive, send)
            return
        work: Coroutine[Any, Any, object]
        if method == "GET":
            work = read_params(service, port, None)
        else:
            body, receive = await _read_body(receive)
            values = _patch_values(headers, body)
            if values is None:
                await self.app(scope, receive, send)
                return
            work = write_params(service, port, values, None, None)
        try:
            answer: Response = JSONResponse(await work)
        except Exception as exc:
            handler = _handler(api, exc)
            if handler is None:
                raise
            answer = handler(Request(scope, receive), exc)
            if inspect.isawaitable(answer):
                answer = await answer
        await answer(scope, receive, send)


def _has_token(scope: Scope, options: ApiOptions) -> bool:
    """The request carries the daemon's token, by the one rule (`token_accepted`).

    A missing or wrong token, or two ``Authorization`` headers, are left to the routes,
    which log it and slow the peer down.
    """
    client = scope.get("client")
    return token_accepted(options, scope["headers"], client[0] if client else "unknown")


def _patch_values(headers: dict[bytes, bytes], body: bytes) -> dict[str, int] | None:
    """The changes of a JSON body `ParamsPatch` accepts, or None (the route answers)."""
    content_type = headers.get(b"content-type", b"").split(b";", 1)[0].strip().lower()
    if content_type != b"application/json":
        return None
    try:
        changes = ParamsPatch.model_validate(json.loads(body))
    except Exception:  # not JSON, not valid: the route says why (422)
        return None
    values: dict[str, int] = changes.model_dump(exclude_unset=True)
    return values


async def _read_body(receive: Receive) -> tuple[bytes, Receive]:
    """The whole request body, and a ``receive`` that hands the same messages on again."""
    messages: list[Message] = []
    while True:
        message = await receive()
        messages.append(message)
        if message["type"] != "http.request" or not message.get("more_body", False):
            break
    body = b"".join(m.get("body", b"") for m in messages if m["type"] == "http.request")

    async def replay() -> Message:
        return messages.pop(0) if messages else await receive()

    return body, replay


def _handler(api: Any, exc: Exception) -> Any:
    """The app's handler for ``exc`` (by its class, nearest first), as the routes get it."""
    handlers = api.exception_handlers
    for cls in type(exc).__mro__:
        if cls in handlers:
            return handlers[cls]
    return None
