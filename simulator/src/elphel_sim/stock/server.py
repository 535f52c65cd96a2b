"""The stock NC393's HTTP surface: parsedit.php on the web port, imgsrv on BASE..BASE+3.

`parsedit_app` is the camera's web server as far as the simulator models it (only
``/parsedit.php``); `imgsrv_app` is one port's image server. Both answer without any
token (as the camera) and with ``Access-Control-Allow-Origin: *``.
"""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Callable

from fastapi import FastAPI, Request
from fastapi.responses import Response
from starlette.concurrency import run_in_threadpool
from starlette.types import Receive, Scope, Send

from elphel_sim.stock.firmware import KNOWN, PORTS, StockFirmware
from elphel_sim.stock.imgsrv import Imgsrv, Reply
from elphel_sim.stock.parsedit import (
    UnknownParameterError,
    parameters_xml,
    parse_query,
    unknown_name_xml,
)

# A frame's pixels are formed only for a client still connected this long after its Exif
# head: one that reads only the head (a frame's number and time) hangs up before.
PIXELS_AFTER_S = 0.5
XML_HEADERS = {"Pragma": "no-cache", "Access-Control-Allow-Origin": "*"}
NOT_IMMEDIATE = (
    "<html><body><p>This simulated NC393 answers parsedit.php in immediate mode only: "
    "add <code>&amp;immediate</code> to the query.</p></body></html>\n"
)


def parsedit_app(firmware: StockFirmware) -> FastAPI:
    """The camera's web server: ``GET /parsedit.php?immediate&...``."""
    app = FastAPI(title="simulated NC393 web server", docs_url=None, redoc_url=None)
    # The endpoints are shared and find the firmware through the request: FastAPI keeps
    # the endpoints it has seen in a process-wide cache, and one that closed over the
    # firmware would keep it (its board and frames) alive for good.
    app.state.firmware = firmware
    app.add_api_route("/parsedit.php", parsedit, methods=["GET"])
    return app


async def parsedit(request: Request) -> Response:
    """``GET /parsedit.php``: read and write parameters, immediate mode only."""
    try:
        query = parse_query(request.url.query, known=KNOWN)
    except UnknownParameterError as e:
        body = unknown_name_xml(e.name)
        return Response(body, media_type="text/xml", headers=XML_HEADERS)
    if not query.immediate:
        return Response(NOT_IMMEDIATE, media_type="text/html", headers=XML_HEADERS)
    before = await run_in_threadpool(request.app.state.firmware.parsedit, query)
    return Response(parameters_xml(before), media_type="text/xml", headers=XML_HEADERS)


def imgsrv_app(
    firmware: StockFirmware, port: int, *, pixels_after_s: float = PIXELS_AFTER_S
) -> FastAPI:
    """The image server of one sensor port: every path is a command sequence.

    A frame not sent before goes out Exif head first; its image is formed and the rest
    sent only if the client is still connected ``pixels_after_s`` later (`HeadFirst`).
    """
    if not 0 <= port < PORTS:
        raise ValueError(f"imgsrv port {port}; allowed: 0..{PORTS - 1}")
    if not pixels_after_s >= 0:
        raise ValueError(f"pixels_after_s={pixels_after_s}; allowed: >= 0")
    server = Imgsrv(firmware, port)
    app = FastAPI(title=f"simulated NC393 imgsrv, port {port}", docs_url=None, redoc_url=None)
    app.router.redirect_slashes = False
    app.state.imgsrv = server  # found through the request, as in `parsedit_app`
    app.state.pixels_after_s = pixels_after_s
    app.add_api_route("/{path:path}", commands, methods=["GET"])
    return app


async def commands(path: str, request: Request) -> Response:
    """``GET /<commands>``: one imgsrv command sequence."""
    server: Imgsrv = request.app.state.imgsrv
    full = path + (f"?{request.url.query}" if request.url.query else "")
    reply = await run_in_threadpool(server.handle, full)
    if reply.rest is not None:
        return HeadFirst(reply, listen_s=request.app.state.pixels_after_s)
    return Response(
        reply.body,
        status_code=reply.status,
        media_type=reply.content_type,
        headers=reply.headers,
    )


class HeadFirst(Response):
    """A frame's answer sent Exif head first, the rest formed only for a client still there.

    The head goes out at once; if the client hangs up within ``listen_s`` (it wanted the
    frame's number and time only), the image is never formed, otherwise ``reply.rest()``
    forms it and the rest follows; ``reply.release()`` then lets go of the frame. The
    length is not known before: no Content-Length, the answer is chunked.
    """

    def __init__(self, reply: Reply, *, listen_s: float) -> None:
        self.reply = reply
        self.listen_s = listen_s
        self.status_code = reply.status
        self.media_type = reply.content_type
        self.background = None
        self.init_headers(reply.headers)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        try:
            start = {"type": "http.response.start", "status": self.status_code}
            await send({**start, "headers": self.raw_headers})
            body = {"type": "http.response.body", "body": self.reply.body, "more_body": True}
            await send(body)
            if self.reply.rest is None or await hung_up(receive, within_s=self.listen_s):
                return
            rest = await run_in_threadpool(self.reply.rest)
            await send({"type": "http.response.body", "body": rest, "more_body": False})
        finally:
            if self.reply.release is not None:
                self.reply.release()


async def hung_up(receive: Receive, *, within_s: float) -> bool:
    """Whether the client closes the connection within ``within_s`` seconds."""
    if within_s <= 0:
        return False
    try:
        async with asyncio.timeout(within_s):
            while (await receive())["type"] != "http.disconnect":
                pass
    except TimeoutError:
        return False
    return True


def consecutive_sockets(
    bind: Callable[[int], socket.socket], *, count: int = PORTS, tries: int = 50
) -> list[socket.socket]:
    """``count`` listening sockets on consecutive free ports (imgsrv's BASE..BASE+3).

    ``bind(port)`` binds one (0 = any free port) and raises OSError if it is taken.
    """
    for _ in range(tries):
        first = bind(0)
        socks = [first]
        base = first.getsockname()[1]
        try:
            for k in range(1, count):
                socks.append(bind(base + k))
        except OSError:
            for s in socks:
                s.close()
            continue
        return socks
    raise OSError(f"no {count} consecutive free ports for imgsrv after {tries} tries")
