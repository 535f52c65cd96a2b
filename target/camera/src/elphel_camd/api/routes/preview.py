"""Routes of a port's live view: JPEG previews, an MJPEG stream and the histogram.

``/ports/{port}/preview`` (JPEG), ``/ports/{port}/preview.mjpeg`` (multipart MJPEG
stream) and ``/ports/{port}/histogram`` (raw value counts with clipped pixels).

Previews are reads: they look at frames the board takes anyway and change nothing. A
preview is rendered once per (frame, scale, options) and shared: a dozen viewers of one
port cost one encode per frame. Streams are bounded in number (`MAX_STREAMS`) and rate.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections import OrderedDict
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query
from fastapi.responses import JSONResponse, Response, StreamingResponse
from starlette.concurrency import run_in_threadpool

from elphel_camd import preview
from elphel_camd.api.deps import READS, FrameQuery, PortPath, Service
from elphel_camd.api.errors import error_responses
from elphel_camd.api.models import Problem
from elphel_camd.boards.base import Frame
from elphel_camd.errors import CameraError, FrameNotAvailableError, ParameterRangeError
from elphel_camd.sensors.lepton35 import Lepton35
from elphel_camd.service import CameraService

log = logging.getLogger(__name__)

router = APIRouter()

MAX_STREAMS = 4  # MJPEG streams served at once (all ports together)
MAX_FPS = 30.0
_CACHE_SIZE = 16
_NEXT_FRAME_TRIES = 3
_THERMAL_TTL_S = 2.0  # how long a Lepton's TLinear setting read over CCI is reused
_SCALES = {"1": 1, "1/1": 1, "1/2": 2, "0.5": 2, "1/4": 4, "0.25": 4, "1/8": 8, "0.125": 8}
_SCALE_ALLOWED = "1, 1/2, 1/4 or 1/8 (also 0.5, 0.25, 0.125)"
BOUNDARY = "frame"

_JPEG = {"image/jpeg": {"schema": {"type": "string", "format": "binary"}}}
_FRAME_HEADERS = {
    "X-Frame-Number": {"description": "frame number of the picture", "schema": {"type": "integer"}},
    "X-Timestamp-Ns": {"description": "its start time, ns", "schema": {"type": "integer"}},
    "X-Image-Width": {"description": "raw frame width, px", "schema": {"type": "integer"}},
    "X-Image-Height": {"description": "raw frame height, px", "schema": {"type": "integer"}},
}

# An enum in the schema: a value outside it is invalid by the schema (422), not by the port.
ScaleQuery = Annotated[
    Literal["1", "1/1", "1/2", "0.5", "1/4", "0.25", "1/8", "0.125"],
    Query(description=f"preview size: {_SCALE_ALLOWED} of the frame"),
]
WbQuery = Annotated[bool, Query(description="grey-world white balance (Bayer sensors)")]
TQuery = Annotated[
    float | None,
    Query(ge=-273.15, le=1000.0, description="thermal: °C at the palette's end (default: auto)"),
]


def parse_scale(scale: str) -> int:
    """The reduction factor of a ``scale=`` value."""
    factor = _SCALES.get(scale.strip())
    if factor is None:
        raise ParameterRangeError("scale", scale, _SCALE_ALLOWED)
    return factor


@dataclass(frozen=True)
class Rendered:
    """One encoded preview and the headers that describe it."""

    jpeg: bytes
    headers: dict[str, str]
    frame: int


class PreviewCache:
    """Encoded previews by (port, frame, options); the newest few are kept."""

    def __init__(self, size: int = _CACHE_SIZE) -> None:
        self._items: OrderedDict[tuple[Any, ...], Rendered] = OrderedDict()
        self._size = size
        self._lock = threading.Lock()
        self._thermal: dict[int, tuple[float, bool, float]] = {}

    def get(self, key: tuple[Any, ...]) -> Rendered | None:
        with self._lock:
            got = self._items.get(key)
            if got is not None:
                self._items.move_to_end(key)
            return got

    def put(self, key: tuple[Any, ...], value: Rendered) -> None:
        with self._lock:
            self._items[key] = value
            while len(self._items) > self._size:
                self._items.popitem(last=False)

    def thermal(self, service: CameraService, port: int, driver: Lepton35) -> tuple[bool, float]:
        """(TLinear on, kelvin per count) of a Lepton, re-read over CCI every 2 s."""
        now = time.monotonic()
        with self._lock:
            cached = self._thermal.get(port)
        if cached is not None and now - cached[0] < _THERMAL_TTL_S:
            return cached[1], cached[2]
        with service.sequencer(port).lock:
            on = driver.radiometry() and driver.tlinear()
            k = driver.tlinear_resolution_k() if on else 0.0
        with self._lock:
            self._thermal[port] = (now, on, k)
        return on, k


class StreamSlots:
    """At most `MAX_STREAMS` MJPEG streams at once."""

    def __init__(self, limit: int = MAX_STREAMS) -> None:
        self.limit = limit
        self._open = 0
        self._lock = threading.Lock()

    def take(self) -> bool:
        with self._lock:
            if self._open >= self.limit:
                return False
            self._open += 1
            return True

    def give(self) -> None:
        with self._lock:
            self._open -= 1


_cache = PreviewCache()
_slots = StreamSlots()


def _capture(service: CameraService, port: int, frame: int | None) -> tuple[Frame, dict[str, Any]]:
    """A frame with its metadata; the next one again if the next one went stale.

    A frame that takes long to form (a large window on a slow image path) can outlive
    the parameter history kept for it; a live view then simply shows the one after.
    """
    for attempt in range(_NEXT_FRAME_TRIES):
        try:
            return service.capture(port, frame=frame)
        except FrameNotAvailableError:
            if frame is not None or attempt == _NEXT_FRAME_TRIES - 1:
                raise
    raise AssertionError("unreachable")


def render(
    service: CameraService,
    port: int,
    *,
    frame: int | None,
    factor: int,
    white_balance: bool = True,
    low_c: float | None = None,
    high_c: float | None = None,
) -> Rendered:
    """The preview of the next frame of a port (or of recent frame ``frame``)."""
    driver = service.sensor(port)
    got, metadata = _capture(service, port, frame)
    thermal = None
    if isinstance(driver, Lepton35):
        on, k = _cache.thermal(service, port, driver)
        thermal = k if on else None
    key = (port, got.frame, got.timestamp_ns, factor, white_balance, thermal, low_c, high_c)
    cached = _cache.get(key)
    if cached is not None:
        return cached
    image = got.image
    if thermal is not None:
        shown = preview.thermal_rgb(
            image, kelvin_per_count=thermal, factor=factor, low_c=low_c, high_c=high_c
        )
    else:
        shown = preview.preview_rgb(
            image,
            factor=factor,
            bayer=metadata["bayer"],
            bits=driver.bits,
            white_balance=white_balance,
        )
    headers = {
        "X-Frame-Number": str(got.frame),
        "X-Timestamp-Ns": str(got.timestamp_ns),
        "X-Image-Width": str(image.shape[1]),
        "X-Image-Height": str(image.shape[0]),
        "X-Preview-Scale": f"1/{factor}",
    }
    if shown.wb_gains is not None:
        headers["X-WB-Gains"] = ",".join(f"{g:.3f}" for g in shown.wb_gains)
    if shown.temperature_c is not None:
        headers["X-Temperature-Min-C"] = f"{shown.temperature_c[0]:.2f}"
        headers["X-Temperature-Max-C"] = f"{shown.temperature_c[1]:.2f}"
        headers["X-Palette"] = ",".join(preview.PALETTE)
    out = Rendered(preview.encode_jpeg(shown.rgb), headers, got.frame)
    _cache.put(key, out)
    return out


@router.get(
    "/ports/{port}/preview",
    dependencies=READS,
    response_class=Response,
    responses={
        200: {
            "content": _JPEG,
            "description": "JPEG of the frame; thermal previews add X-Temperature-Min-C, "
            "X-Temperature-Max-C and X-Palette (colours cold to hot)",
            "headers": _FRAME_HEADERS,
        },
        **error_responses(401, 404, 422, 501, 503, 504),
    },
)
def get_preview(
    service: Service,
    port: PortPath,
    frame: FrameQuery = None,
    scale: ScaleQuery = "1/4",
    wb: WbQuery = True,
    tmin: TQuery = None,
    tmax: TQuery = None,
) -> Response:
    """A JPEG preview of the next frame (or recent frame ``frame``), for looking.

    Bayer frames are demosaiced by binning and white-balanced on their grey world; the
    Lepton's radiometric frames are false-coloured between ``tmin`` and ``tmax`` °C (by
    default the frame's 1st and 99th percentiles). Frame number and start time are in
    ``X-Frame-Number`` and ``X-Timestamp-Ns``.
    """
    got = render(
        service,
        port,
        frame=frame,
        factor=parse_scale(scale),
        white_balance=wb,
        low_c=tmin,
        high_c=tmax,
    )
    return Response(
        got.jpeg, media_type="image/jpeg", headers={**got.headers, "Cache-Control": "no-store"}
    )


@router.get(
    "/ports/{port}/preview.mjpeg",
    dependencies=READS,
    response_class=StreamingResponse,
    responses={
        200: {
            "content": {
                f"multipart/x-mixed-replace; boundary={BOUNDARY}": {
                    "schema": {"type": "string", "format": "binary"}
                }
            },
            "description": "one JPEG part per frame; each part carries Content-Length, "
            "X-Frame-Number and X-Timestamp-Ns (and the thermal headers of /preview)",
        },
        429: {"model": Problem, "description": f"already {MAX_STREAMS} streams open"},
        **error_responses(401, 404, 422, 501, 503, 504),
    },
)
async def get_preview_stream(
    service: Service,
    port: PortPath,
    scale: ScaleQuery = "1/4",
    fps: Annotated[float, Query(gt=0, le=MAX_FPS, description="most frames per second")] = 10.0,
    count: Annotated[int | None, Query(ge=1, le=1_000_000, description="end after N")] = None,
    wb: WbQuery = True,
    tmin: TQuery = None,
    tmax: TQuery = None,
) -> Response:
    """Live view: a multipart MJPEG stream of the port's frames, at most ``fps`` a second.

    Frames the encoder cannot keep up with are skipped (the next part is the newest
    frame). At most `MAX_STREAMS` streams are served at once; more get 429.
    """
    factor = parse_scale(scale)
    if not _slots.take():
        return JSONResponse(
            status_code=429,
            content={
                "detail": f"{MAX_STREAMS} preview streams are open already; close one "
                "or poll /preview",
                "error": "too_many_streams",
            },
        )

    def newest() -> Awaitable[Rendered]:
        """The next frame's preview, made off the event loop."""
        return run_in_threadpool(
            render,
            service,
            port,
            frame=None,
            factor=factor,
            white_balance=wb,
            low_c=tmin,
            high_c=tmax,
        )

    try:
        # The first picture is made before the answer starts, so errors get their status.
        first = await newest()
    except BaseException:
        _slots.give()
        raise
    return StreamingResponse(
        _parts(first, newest, port=port, period_s=1.0 / fps, count=count),
        media_type=f"multipart/x-mixed-replace; boundary={BOUNDARY}",
        headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"},
    )


async def _parts(
    first: Rendered,
    newest: Callable[[], Awaitable[Rendered]],
    *,
    port: int,
    period_s: float,
    count: int | None,
) -> AsyncIterator[bytes]:
    """The stream's parts, one every ``period_s`` at most; gives back its slot at the end."""
    try:
        got, sent = first, 0
        while True:
            started = time.monotonic()
            yield _part(got)
            sent += 1
            if count is not None and sent >= count:
                break
            wait = period_s - (time.monotonic() - started)
            if wait > 0:
                await asyncio.sleep(wait)
            try:
                got = await newest()
            except (CameraError, TimeoutError, ValueError) as e:
                log.error("port %d: preview stream ended: %s", port, e)
                break
    finally:
        _slots.give()


def _part(got: Rendered) -> bytes:
    """One multipart part: the JPEG with its length and headers."""
    head = "".join(f"{k}: {v}\r\n" for k, v in got.headers.items())
    return (
        (
            f"--{BOUNDARY}\r\nContent-Type: image/jpeg\r\n"
            f"Content-Length: {len(got.jpeg)}\r\n{head}\r\n"
        ).encode()
        + got.jpeg
        + b"\r\n"
    )


@router.get(
    "/ports/{port}/histogram",
    dependencies=READS,
    responses=error_responses(401, 404, 422, 501, 503, 504),
)
def get_histogram(service: Service, port: PortPath, frame: FrameQuery = None) -> JSONResponse:
    """Raw value counts of the next frame (or recent frame ``frame``) per colour.

    64 equal bins over 0..2**bits; ``clipped_high`` counts pixels at full scale (over-
    exposed), ``clipped_low`` pixels at 0.
    """
    driver = service.sensor(port)
    got, metadata = _capture(service, port, frame)
    counts = preview.histogram(got.image, bayer=metadata["bayer"], bits=driver.bits)
    return JSONResponse(
        {"port": port, "frame": got.frame, "timestamp_ns": got.timestamp_ns, **counts}
    )
