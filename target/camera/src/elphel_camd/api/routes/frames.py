"""Routes of a port's frames: ``GET /ports/{port}/frame`` and ``POST /ports/{port}/capture``.

A capture answers a 16-bit TIFF whose pages carry each frame's JSON metadata; a burst
(``count=N``) is streamed page by page as the frames come.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator, Iterator
from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi.responses import JSONResponse, StreamingResponse

from elphel_camd.api import tiff
from elphel_camd.api.deps import READS, WRITES, FrameQuery, PortPath, Service
from elphel_camd.api.errors import error_responses
from elphel_camd.api.models import FrameInfo

log = logging.getLogger(__name__)

router = APIRouter()

_TIFF_CONTENT = {"image/tiff": {"schema": {"type": "string", "format": "binary"}}}


@router.get(
    "/ports/{port}/frame",
    response_model=FrameInfo,
    dependencies=READS,
    responses=error_responses(401, 404),
)
def get_frame(service: Service, port: PortPath) -> JSONResponse:
    """The current frame number of a port and when it started."""
    seq = service.sequencer(port)
    return JSONResponse(
        {"port": port, "frame": seq.this_frame, "timestamp_ns": seq.this_timestamp_ns}
    )


@router.post(
    "/ports/{port}/capture",
    dependencies=WRITES,
    response_class=StreamingResponse,
    responses={
        200: {"content": _TIFF_CONTENT, "description": "16-bit TIFF, one page per frame"},
        **error_responses(401, 404, 422, 501, 503, 504),
    },
)
def capture(
    service: Service,
    port: PortPath,
    frame: FrameQuery = None,
    count: Annotated[int, Query(ge=1, le=1024, description="consecutive frames")] = 1,
) -> StreamingResponse:
    """The next frame (or recent frame ``frame``) as a 16-bit TIFF with its metadata.

    With ``count=N``, N consecutive frames from there as a multi-page TIFF, sent page
    by page as the frames come. Each page's ImageDescription is that frame's JSON
    metadata; the first frame's number is in ``X-Frame-Number``.
    """
    frames = service.burst(port, count, frame=frame)
    first, metadata = next(frames)  # errors before the answer starts get their status
    headers = {"X-Frame-Number": str(first.frame), "X-Frame-Count": str(count)}
    if count == 1:
        # Known length: no chunked encoding, and the pixels go out without a copy.
        chunks, length = tiff.single(first.image, {"shape": list(first.image.shape), **metadata})

        async def one_page() -> AsyncIterator[bytes | memoryview]:
            for chunk in chunks:
                yield chunk

        return StreamingResponse(
            one_page(),
            media_type="image/tiff",
            headers={**headers, "Content-Length": str(length)},
        )

    def pages() -> Iterator[tuple[Any, dict[str, Any]]]:
        yield first.image, metadata
        try:
            for got, meta in frames:
                yield got.image, meta
        except Exception as e:
            # The status is sent already: end the stream short; the client sees fewer
            # pages than X-Frame-Count.
            log.error("port %d: burst ended early: %s", port, e)

    return StreamingResponse(tiff.stream(pages(), count), media_type="image/tiff", headers=headers)
