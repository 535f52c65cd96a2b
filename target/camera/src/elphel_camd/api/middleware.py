"""ASGI middleware of the API: the request body limit, the Host allow-list, safe headers.

`BodyLimit` answers 413 to bodies over a size, declared (``Content-Length``) or sent
(chunked: such a body is read here, up to the limit, before the app sees it, so the
answer is 413 and not the framework's 400 for a body it could not read). `HostAllowList`
answers 421 to requests whose ``Host`` names a host the daemon was not told it is: a web
page that re-binds its own DNS name to the camera's address (DNS rebinding) sends its own
name and is refused. `SecurityHeaders` gives every answer ``X-Content-Type-Options:
nosniff`` and ``Referrer-Policy: no-referrer``, and every HTML answer (the control page
at ``/`` and ``/web/index.html``, ``/docs``) a Content-Security-Policy that allows only
this daemon and no framing (`HTML_CSP`, unless the answer brings a stricter one of its own).

The daemon's own server (`elphel_camd.serving`) writes `ANSWER_HEADERS` itself, on every
answer including those it makes without the app (400 for a malformed request, 503 over
the connection limit); it names the headers it writes in the request's scope
(`SERVER_HEADERS_EXTENSION`) and `SecurityHeaders` leaves those to it, so each header is
sent once whichever server runs the app.
"""

from __future__ import annotations

import ipaddress
import json
from collections.abc import Iterable

from starlette.datastructures import MutableHeaders
from starlette.types import ASGIApp, Message, Receive, Scope, Send

# Only this origin; previews are shown from blob: URLs the page makes itself; no page of
# another site may frame these (clickjacking).
HTML_CSP = (
    "default-src 'self'; img-src 'self' blob: data:; connect-src 'self'; "
    "style-src 'self'; script-src 'self'; object-src 'none'; base-uri 'none'; "
    "form-action 'self'; frame-ancestors 'none'"
)

# On every answer, whatever its kind or who makes it.
ANSWER_HEADERS = (("X-Content-Type-Options", "nosniff"), ("Referrer-Policy", "no-referrer"))

# A scope extension: the lower-case names of the headers the server writes on every answer.
SERVER_HEADERS_EXTENSION = "elphel.server_headers"


async def _problem(send: Send, status: int, body: dict[str, object]) -> None:
    data = json.dumps(body).encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(data)).encode()),
            ],
        }
    )
    await send({"type": "http.response.body", "body": data})


class BodyLimit:
    """Answer 413 to request bodies over ``max_bytes`` (declared or actually sent)."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def _reject(self, send: Send) -> None:
        await _problem(
            send,
            413,
            {
                "detail": f"request body over {self.max_bytes} bytes (limit max_body_bytes)",
                "error": "too_large",
                "limit": "max_body_bytes",
                "maximum": self.max_bytes,
            },
        )

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared: int | None = None
        for key, value in scope["headers"]:
            if key == b"content-length":
                declared = int(value) if value.isdigit() else None
        if declared is not None:
            if declared > self.max_bytes:
                await self._reject(send)
                return
            await self.app(scope, receive, send)  # the server stops at the declared length
            return
        # No length (chunked, or no body): read what comes, at most the limit, then replay.
        chunks: list[bytes] = []
        received = 0
        more = True
        while more:
            message = await receive()
            if message["type"] != "http.request":
                await self.app(scope, _replay([], message, receive), send)
                return
            chunk = message.get("body", b"")
            received += len(chunk)
            if received > self.max_bytes:
                await self._reject(send)
                return
            chunks.append(chunk)
            more = message.get("more_body", False)
        body: Message = {"type": "http.request", "body": b"".join(chunks), "more_body": False}
        await self.app(scope, _replay([body], None, receive), send)


def _replay(messages: list[Message], last: Message | None, receive: Receive) -> Receive:
    pending = list(messages) + ([last] if last is not None else [])

    async def replayed() -> Message:
        if pending:
            return pending.pop(0)
        return await receive()

    return replayed


def host_name(header: str) -> str:
    """The host of a ``Host`` header, without the port, lower-case (IPv6 unbracketed)."""
    value = header.strip().lower()
    if value.startswith("["):
        return value[1 : value.find("]")] if "]" in value else value
    return value.rsplit(":", 1)[0] if value.count(":") == 1 else value


def is_ip_literal(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


class HostAllowList:
    """Answer 421 unless ``Host`` is an IP address, ``localhost``, or a name allowed.

    An IP address in ``Host`` cannot come from a rebound DNS name, so addresses always
    pass; names must be listed (``allowed_hosts``, e.g. the camera's DNS name). ``*``
    allows every name (behind a reverse proxy that checks it).
    """

    def __init__(self, app: ASGIApp, allowed: Iterable[str]) -> None:
        self.app = app
        self.allowed = frozenset(host_name(h) for h in allowed) | {"localhost"}
        self.any = "*" in self.allowed

    def allows(self, header: str) -> bool:
        name = host_name(header)
        return self.any or name in self.allowed or is_ip_literal(name)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        header = ""
        for key, value in scope["headers"]:
            if key == b"host":
                header = value.decode("latin-1")
                break
        if not self.allows(header):
            await _problem(
                send,
                421,
                {
                    "detail": f"Host {header!r} is not a name of this camera; allowed: an IP "
                    f"address or {', '.join(sorted(self.allowed))} (setting allowed_hosts)",
                    "error": "host_not_allowed",
                    "limit": "allowed_hosts",
                },
            )
            return
        await self.app(scope, receive, send)


class SecurityHeaders:
    """Headers every answer carries, and the Content-Security-Policy of HTML answers."""

    def __init__(self, app: ASGIApp, html_csp: str = HTML_CSP) -> None:
        self.app = app
        self.html_csp = html_csp

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        by_server = scope.get("extensions", {}).get(SERVER_HEADERS_EXTENSION, frozenset())

        async def send_safe(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = MutableHeaders(scope=message)
                for name, value in ANSWER_HEADERS:
                    if name.lower() not in by_server:
                        headers.setdefault(name, value)
                if headers.get("content-type", "").lower().startswith("text/html"):
                    headers.setdefault("Content-Security-Policy", self.html_csp)
                    headers.setdefault("X-Frame-Options", "DENY")
            await send(message)

        await self.app(scope, receive, send_safe)
