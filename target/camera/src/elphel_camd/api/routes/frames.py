"""Routes of a port's frames: ``GET /ports/{port}/frame`` and ``POST /ports/{port}/capture``.

A capture answers a 16-bit TIFF whose pages carry each frame's JSON metadata; a burst
(``count=N``) is streamed page by page as the frames come. Captures wait for frames in the
service's capture pool, never in the pool that serves the other requests. A burst answers
every frame it promised or breaks the connection: if a frame fails after the status went
out, the body ends without its final chunk, so no client takes a short TIFF for a whole one.
A burst that a classic TIFF cannot hold (4 GiB) at the port's window is refused before
anything is captured: 422 naming the largest count for that window.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import AsyncIterator, Generator
from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi.responses import JSONResponse, Response, StreamingResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from elphel_camd.api import tiff
from elphel_camd.api.deps import READS, WRITES, FrameQuery, PortPath, Service
from elphel_camd.api.errors import error_responses, problem
from elphel_camd.api.models import FrameInfo
from elphel_camd.boards.base import Frame
from elphel_camd.capture import CaptureBusyError
from elphel_camd.errors import FrameNotAvailableError
from elphel_camd.sequencer import MAX_AHEAD
from elphel_camd.service import CameraService

log = logging.getLogger(__name__)

router = APIRouter()

_TIFF_CONTENT = {"image/tiff": {"schema": {"type": "string", "format": "binary"}}}


@router.get(
    "/ports/{port}/frame",
    response_model=FrameInfo,
    dependencies=READS,
    responses=error_responses(401, 404),
)
async def get_frame(service: Service, port: PortPath) -> JSONResponse:
    """The current frame number of a port and when it started."""
    seq = service.sequencer(port)
    return JSONResponse(
        {"port": port, "frame": seq.this_frame, "timestamp_ns": seq.this_timestamp_ns}
    )


class BurstBrokenError(RuntimeError):
    """A burst failed after its first page was sent; the connection is broken off."""


@router.post(
    "/ports/{port}/capture",
    dependencies=WRITES,
    response_class=StreamingResponse,
    responses={
        200: {"content": _TIFF_CONTENT, "description": "16-bit TIFF, one page per frame"},
        **error_responses(401, 404, 422, 501, 503, 504),
    },
)
async def capture(
    service: Service,
    port: PortPath,
    frame: FrameQuery = None,
    count: Annotated[int, Query(ge=1, le=1024, description="consecutive frames")] = 1,
) -> Response:
    """The next frame (or recent frame ``frame``) as a 16-bit TIFF with its metadata.

    With ``count=N``, N consecutive frames from there as a multi-page TIFF, sent page
    by page as the frames come; the daemon holds the N frames until they are sent, and
    if one still fails the connection breaks off before the end of the body (never a
    short TIFF with a 200). Each page's ImageDescription is that frame's JSON metadata,
    and each page has the size of its own frame (a window change during the burst
    changes the page size, and WOI_WIDTH/WOI_HEIGHT of that page); the first frame's
    number is in ``X-Frame-Number``. 422 (naming the largest count) when ``count`` frames
    of the window, the largest one scheduled, would not fit in a TIFF's 4 GiB; 503 when
    the capture wait pool is full.
    """
    too_many = _over_tiff_limit(service, port, count, frame)
    if too_many is not None:
        return too_many
    frames = service.burst(port, count, frame=frame)
    first = await _next(service, frames)  # errors here still get their status
    assert first is not None
    got, metadata = first
    headers = {"X-Frame-Number": str(got.frame), "X-Frame-Count": str(count)}
    if count == 1:
        frames.close()
        return _one_page(got, metadata, headers)

    async def body() -> AsyncIterator[bytes | memoryview]:
        yield tiff.header()
        offset, page = 8, first
        try:
            for index in range(count):
                last = index == count - 1
                chunks, offset = tiff.page_chunks(page[0].image, page[1], offset=offset, last=last)
                for chunk in chunks:
                    yield chunk
                if not last:
                    page = await _following(service, frames, port, index + 1, count)
        finally:
            # A frame still being waited for in its thread: the generator closes when
            # that wait ends and it is collected (the frames it held are released then).
            with contextlib.suppress(ValueError):
                frames.close()

    return StreamingResponse(body(), media_type="image/tiff", headers=headers)


def _one_page(got: Frame, metadata: dict[str, Any], headers: dict[str, str]) -> StreamingResponse:
    """One frame's TIFF, of known length: no chunked encoding, the pixels sent uncopied."""
    chunks, length = tiff.single(got.image, _with_shape(got, metadata))

    async def one_page() -> AsyncIterator[bytes | memoryview]:
        for chunk in chunks:
            yield chunk

    return StreamingResponse(
        one_page(), media_type="image/tiff", headers={**headers, "Content-Length": str(length)}
    )


Page = tuple[Frame, dict[str, Any]]


def burst_window(service: CameraService, port: int, frame: int | None) -> tuple[int, int]:
    """The largest window (width, height) of a burst's frames known now.

    From the burst's first frame to the last frame changes can be scheduled for: the
    window in effect, or a larger one already scheduled.
    """
    seq = service.sequencer(port)
    first = min(seq.this_frame + 1, seq.this_frame if frame is None else frame)
    now = seq.state_at(seq.this_frame)
    windows = {(now["WOI_WIDTH"], now["WOI_HEIGHT"])}
    for n in range(first, seq.this_frame + MAX_AHEAD + 1):
        with contextlib.suppress(FrameNotAvailableError):
            state = seq.state_at(n)
            windows.add((state["WOI_WIDTH"], state["WOI_HEIGHT"]))
    return max(windows, key=lambda window: window[0] * window[1])


def _over_tiff_limit(
    service: CameraService, port: int, count: int, frame: int | None
) -> JSONResponse | None:
    """The 422 answer of a burst too large for one TIFF at the port's window, or None."""
    if count == 1:
        return None
    width, height = burst_window(service, port, frame)
    largest = tiff.largest_count(width, height)
    if count <= largest:
        return None
    allowed = f"1..{largest} frames of the window {width}x{height} (a TIFF holds 4 GiB)"
    return problem(
        422,
        {
            "detail": f"count={count} frames of {width}x{height} do not fit in one TIFF "
            f"(4 GiB); allowed: {allowed}; capture in parts or shrink the window",
            "error": "parameter_range",
            "parameter": "count",
            "value": count,
            "allowed": allowed,
        },
    )


async def _next(service: CameraService, frames: Generator[Page, None, None]) -> Page | None:
    """The burst's next frame, waited for in the capture pool (503 if that is full)."""
    try:
        result = await service.capture_pool.run(lambda: next(frames, None))
    except CaptureBusyError as e:
        raise StarletteHTTPException(503, detail=str(e), headers={"Retry-After": "1"}) from e
    return result


def _with_shape(got: Frame, metadata: dict[str, Any]) -> dict[str, Any]:
    return {"shape": list(got.image.shape), **metadata}


async def _following(
    service: CameraService, frames: Generator[Page, None, None], port: int, sent: int, count: int
) -> Page:
    """The burst's next frame after ``sent`` pages went out; BurstBrokenError if none comes."""
    try:
        following = await _next(service, frames)
    except Exception as e:
        log.error("port %d: burst broken off after %d of %d frames: %s", port, sent, count, e)
        raise BurstBrokenError(
            f"port {port}: burst broken off after {sent} of {count} frames: {e}"
        ) from e
    if following is None:
        raise BurstBrokenError(f"port {port}: burst ended after {sent}")
    return following
