"""The stock NC393's HTTP surface: parsedit.php on the web port, imgsrv on BASE..BASE+3.

`parsedit_app` is the camera's web server as far as the simulator models it (only
``/parsedit.php``); `imgsrv_app` is one port's image server. Both answer without any
token (as the camera) and with ``Access-Control-Allow-Origin: *``.
"""

from __future__ import annotations

import socket
from collections.abc import Callable

from fastapi import FastAPI, Request
from fastapi.responses import Response
from starlette.concurrency import run_in_threadpool

from elphel_sim.stock.firmware import KNOWN, PORTS, StockFirmware
from elphel_sim.stock.imgsrv import Imgsrv
from elphel_sim.stock.parsedit import (
    UnknownParameterError,
    parameters_xml,
    parse_query,
    unknown_name_xml,
)

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


def imgsrv_app(firmware: StockFirmware, port: int) -> FastAPI:
    """The image server of one sensor port: every path is a command sequence."""
    if not 0 <= port < PORTS:
        raise ValueError(f"imgsrv port {port}; allowed: 0..{PORTS - 1}")
    server = Imgsrv(firmware, port)
    app = FastAPI(title=f"simulated NC393 imgsrv, port {port}", docs_url=None, redoc_url=None)
    app.router.redirect_slashes = False
    app.state.imgsrv = server  # found through the request, as in `parsedit_app`
    app.add_api_route("/{path:path}", commands, methods=["GET"])
    return app


async def commands(path: str, request: Request) -> Response:
    """``GET /<commands>``: one imgsrv command sequence."""
    server: Imgsrv = request.app.state.imgsrv
    full = path + (f"?{request.url.query}" if request.url.query else "")
    reply = await run_in_threadpool(server.handle, full)
    return Response(
        reply.body,
        status_code=reply.status,
        media_type=reply.content_type,
        headers=reply.headers,
    )


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
