"""Route of the event stream: ``GET /events`` (server-sent events).

Each event goes out as ``id:``, ``event:`` and one JSON ``data:`` line. A client resumes
with ``Last-Event-ID``; one that falls a queue's length behind gets a ``dropped`` event
and the stream ends; the number of streams is bounded (503 beyond it); a daemon shutting
down ends every stream at once. A stream that sent no event of the types it asked for in
``stream_idle_s`` (keepalive comments do not count) ends with a comment saying so: an
idle stream does not hold one of the bounded slots for ever, and a client that still
wants events reconnects with ``Last-Event-ID`` and misses none.
"""

from __future__ import annotations

import asyncio
import json
import math
import time
from collections.abc import Callable
from typing import Annotated, Any

import anyio
from fastapi import APIRouter, Header, Query
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.responses import Response
from starlette.types import Receive, Scope, Send

from elphel_camd.api.deps import READS, Options, Service
from elphel_camd.api.errors import error_responses
from elphel_camd.events import (
    EVENT_TYPES,
    EventHub,
    HubClosedError,
    Subscription,
    TooManyStreamsError,
)

router = APIRouter()

# How long the last words (a ``dropped`` notice, the end of the body) may take to go out.
_FAREWELL_S = 1.0
# The ASGI scope extension through which the server lets a stream cut its connection
# (elphel_camd.serving): what is buffered goes out if the client reads it within
# _FAREWELL_S, then the connection is dropped. Without it the response just ends.
CUT_EXTENSION = "elphel.cut"
# ... and fix its kernel send buffer: else the kernel grows it to megabytes for a client
# that does not read, and the client is found to lag only minutes later.
SEND_BUFFER_EXTENSION = "elphel.send_buffer"
STREAM_SEND_BUFFER = 8 * 1024  # events are ~100 bytes: ample for a client that reads
_BATCH = 32  # queued events sent in one write at most


def dropped_notice(sub: Subscription, reason: str, last_id: int | None) -> bytes:
    body: dict[str, Any] = {"dropped": sub.dropped or sub.missed, "reason": reason}
    if reason == "slow":
        body["queue"] = sub.maxlen
    if last_id is not None:
        body["last_id"] = last_id
    return f"event: dropped\ndata: {json.dumps(body, separators=(',', ':'))}\n\n".encode()


class EventStream(Response):
    """The streaming answer of one subscription (a raw ASGI response).

    Ends when ``count`` events went out, when the client leaves, when it falls behind
    (after a ``dropped`` notice) or when the hub closes.
    """

    media_type = "text/event-stream"

    def __init__(
        self,
        hub: EventHub,
        sub: Subscription,
        *,
        keepalive_s: float,
        count: int | None,
        idle_s: float = math.inf,
    ) -> None:
        # No Response.__init__: it would declare Content-Length: 0 for the empty body.
        self.status_code = 200
        self.background = None
        self.raw_headers = [
            (b"content-type", b"text/event-stream; charset=utf-8"),
            (b"cache-control", b"no-cache"),
            (b"x-accel-buffering", b"no"),
        ]
        self.hub, self.sub = hub, sub
        self.keepalive_s, self.count, self.idle_s = keepalive_s, count, idle_s

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        sub = self.sub
        extensions = scope.get("extensions") or {}
        cut: Callable[[float], None] | None = extensions.get(CUT_EXTENSION)
        limit_send_buffer = extensions.get(SEND_BUFFER_EXTENSION)
        if limit_send_buffer is not None:
            limit_send_buffer(STREAM_SEND_BUFFER)
        try:
            await send({"type": "http.response.start", "status": 200, "headers": self.raw_headers})
            async with anyio.create_task_group() as tg:
                tg.start_soon(self._watch_disconnect, receive, tg.cancel_scope)
                with anyio.CancelScope() as pump:
                    sub.interrupt = pump.cancel
                    await self._pump(send)
                with anyio.move_on_after(_FAREWELL_S):
                    if sub.overflowed:
                        await send(_body(dropped_notice(sub, "slow", self._sent_id)))
                    await send({"type": "http.response.body", "body": b"", "more_body": False})
                if sub.overflowed and cut is not None:
                    # A client cut off is not kept alive for another request, and one
                    # that does not read does not hold the connection open.
                    cut(_FAREWELL_S)
                tg.cancel_scope.cancel()
        finally:
            self.hub.unsubscribe(sub)

    _sent_id: int | None = None  # the last event sent

    async def _pump(self, send: Send) -> None:
        sub = self.sub
        await send(_body(b"retry: 2000\n\n"))
        if sub.missed:
            await send(_body(dropped_notice(sub, "replay", None)))
        sent = 0
        idle_until = time.monotonic() + self.idle_s
        while self.count is None or sent < self.count:
            idle_left_s = idle_until - time.monotonic()
            if idle_left_s <= 0:
                await send(_body(b": no event for %g s: closed\n\n" % self.idle_s))
                return
            event = await sub.get(min(self.keepalive_s, idle_left_s))
            if sub.overflowed or sub.closed:
                break
            if event is None:
                if idle_until > time.monotonic():
                    await send(_body(b": keepalive\n\n"))
                continue
            idle_until = time.monotonic() + self.idle_s
            # What else is queued goes out with it: one write for a burst of events.
            batch = [event]
            while len(batch) < _BATCH and (self.count is None or sent + len(batch) < self.count):
                more = sub.pop()
                if more is None:
                    break
                batch.append(more)
            await send(_body(b"".join(e.sse for e in batch)))
            self._sent_id = batch[-1].id
            sent += len(batch)

    @staticmethod
    async def _watch_disconnect(receive: Receive, scope: anyio.CancelScope) -> None:
        while True:
            message = await receive()
            if message["type"] == "http.disconnect":
                scope.cancel()
                return


def _body(data: bytes) -> dict[str, Any]:
    return {"type": "http.response.body", "body": data, "more_body": True}


@router.get(
    "/events",
    dependencies=READS,
    response_class=Response,
    responses={
        200: {
            "content": {"text/event-stream": {"schema": {"type": "string"}}},
            "description": "server-sent events: frame, params, error (and dropped)",
        },
        **error_responses(401, 422, 503),
    },
)
async def events(
    service: Service,
    options: Options,
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
    last_event_id: Annotated[
        str | None,
        Header(
            alias="Last-Event-ID",
            description="resume after this event id (replayed from a short buffer)",
        ),
    ] = None,
) -> Response:
    """Server-sent events: ``frame``, ``params``, ``error``, each with an id and JSON data.

    ``Last-Event-ID`` resumes after that id (ids keep increasing across daemon restarts);
    events the replay buffer no longer holds are announced by a ``dropped`` event with
    ``reason: replay``. A client that falls a queue's length behind gets a ``dropped``
    event with ``reason: slow`` and the stream ends; acquisition never waits for it.
    A stream without an event of its types for the daemon's ``stream_idle_s`` (300 s by
    default; keepalive comments do not count) ends; reconnect with ``Last-Event-ID``.
    503 when as many streams are open as the daemon allows.
    """
    hub = service.events
    resume: int | None = None
    if last_event_id is not None and last_event_id.strip():
        try:
            resume = int(last_event_id.strip())
        except ValueError:
            raise StarletteHTTPException(
                422, detail=f"Last-Event-ID {last_event_id!r}: give an event id (an integer)"
            ) from None
    try:
        sub = hub.subscribe(
            types.split(","), port=port, loop=asyncio.get_running_loop(), last_id=resume
        )
    except TooManyStreamsError as e:
        raise StarletteHTTPException(
            503, detail=f"event stream limit: {e}", headers={"Retry-After": "5"}
        ) from e
    except HubClosedError as e:
        raise StarletteHTTPException(503, detail=str(e)) from e
    return EventStream(
        hub, sub, keepalive_s=options.keepalive_s, count=count, idle_s=options.stream_idle_s
    )
