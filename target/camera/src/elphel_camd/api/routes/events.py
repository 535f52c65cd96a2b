"""Route of the event stream: ``GET /events`` (server-sent events)."""

from __future__ import annotations

import json
from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import APIRouter, Query
from fastapi.responses import StreamingResponse

from elphel_camd.api.deps import READS, Options, Service
from elphel_camd.api.errors import error_responses
from elphel_camd.events import EVENT_TYPES

router = APIRouter()


@router.get(
    "/events",
    dependencies=READS,
    response_class=StreamingResponse,
    responses={
        200: {
            "content": {"text/event-stream": {"schema": {"type": "string"}}},
            "description": "server-sent events: frame, params, error (and dropped)",
        },
        **error_responses(401, 422),
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
) -> StreamingResponse:
    """Server-sent events: ``frame``, ``params`` and ``error``, each a JSON ``data`` line.

    A client that falls more than the queue size behind loses the oldest events and
    gets a ``dropped`` event with the running count; acquisition never waits for it.
    """
    hub = service.events
    sub = hub.subscribe(types.split(","), port=port)
    keepalive_s = options.keepalive_s

    async def stream() -> AsyncIterator[str]:
        try:
            yield "retry: 2000\n\n"
            sent = reported = 0
            while count is None or sent < count:
                event = await sub.get(keepalive_s)
                if sub.dropped > reported:
                    reported = sub.dropped
                    yield f"event: dropped\ndata: {json.dumps({'dropped': reported})}\n\n"
                if event is None:
                    yield ": keepalive\n\n"
                    continue
                data = json.dumps(event.data, separators=(",", ":"))
                yield f"id: {event.id}\nevent: {event.type}\ndata: {data}\n\n"
                sent += 1
        finally:
            hub.unsubscribe(sub)

    return StreamingResponse(
        stream(),
        media_type="text/event-stream",
        headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
    )
