"""Typed REST client of elphel-camd (docs/rest-api.md).

What it decodes lives next to it: frames and multi-page bursts in
:mod:`elphel_host.camera.frames`, the event stream in :mod:`elphel_host.camera.events`.
When a failed request is sent again is :mod:`elphel_host.camera.retry`'s policy.
"""

from __future__ import annotations

import socket
from collections.abc import Iterator, Mapping
from typing import Any

import httpx

from elphel_host import strict_json
from elphel_host.camera.answers import (
    EVENT_MODELS,
    FrameAnswer,
    FrameMetadata,
    InfoAnswer,
    PatchAnswer,
    checked,
    checked_dict,
)
from elphel_host.camera.events import CameraEvent, SSEParser
from elphel_host.camera.frames import (
    CapturedBurst,
    CapturedFrame,
    read_partial_tiff,
    read_tiff_metadata,
    read_tiff_pages,
)
from elphel_host.camera.retry import Backoff, retryable
from elphel_host.camera.staging import Applied, Staging
from elphel_host.closing import Closing
from elphel_host.errors import (
    CameraAuthError,
    CameraClientError,
    DeviceAnswerError,
    DeviceLimitError,
    DeviceTimeout,
)
from elphel_host.limits import Deadline, HostLimits, bounded_lines, check_declared, read_bounded
from elphel_host.shown import shown

API = "/api/v1"
INFO_TIMEOUT_S = 5.0  # GET /info answers at once; longer means no HTTP server there
_NODELAY = [(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)]


class CameraHTTPError(CameraClientError):
    """The daemon answered with an error status; ``body`` is its JSON error object.

    For a rejected value ``parameter``, ``value`` and ``allowed`` say which and why.
    """

    def __init__(self, message: str, *, status: int, body: Mapping[str, Any]) -> None:
        super().__init__(message)
        self.status = status
        self.body = dict(body)

    @property
    def parameter(self) -> str | None:
        return self.body.get("parameter")

    @property
    def value(self) -> Any:
        return self.body.get("value")

    @property
    def allowed(self) -> str | None:
        return self.body.get("allowed")


class CameraUnauthorizedError(CameraHTTPError, CameraAuthError):
    """401/403: no token or a wrong one."""


class PartialBurstError(CameraClientError):
    """A burst broke off before its last frame; ``partial`` holds the complete pages.

    ``partial.complete`` is False; its ``tiff`` is a valid multi-page TIFF of the frames
    received (``elphel camera capture --keep-partial`` writes it).
    """

    def __init__(self, message: str, *, partial: CapturedBurst) -> None:
        super().__init__(message)
        self.partial = partial


class CameraClient(Staging, Closing):
    """Talks to one camera daemon.

    Parameters
    ----------
    url
        Base URL of the daemon, e.g. ``http://127.0.0.1:8000``.
    token
        Bearer token for writes (capture counts as one); None for read-only use.
    timeout_s
        Timeout of each read and of making the connection.
    retry_s
        How long to keep retrying while the daemon cannot be reached (a restart): reads
        and other idempotent requests are retried after any connection failure, PATCH
        and capture only when the connection could not be made (so a change is never
        applied twice); the event stream reconnects with the last event id it got. 0
        gives up at once.
    transport
        httpx transport to use instead of the network (tests).
    limits
        Sizes and deadlines the daemon's answers are held to (default: `HostLimits.from_env`).

    Examples
    --------
    >>> with CameraClient("http://127.0.0.1:8000", token) as cam:  # doctest: +SKIP
    ...     cam.set_params({"EXPOS": 5000}, ahead=3)
    ...     with cam.staged({"WOI_WIDTH": 640, "WOI_HEIGHT": 480}):
    ...         frame = cam.capture()
    """

    def __init__(
        self,
        url: str,
        token: str | None = None,
        *,
        timeout_s: float = 30.0,
        retry_s: float = 10.0,
        transport: httpx.BaseTransport | None = None,
        limits: HostLimits | None = None,
    ) -> None:
        if not url.startswith(("http://", "https://")):
            raise ValueError(f"camera url {url!r}; allowed: http://HOST:PORT or https://...")
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.url = url.rstrip("/")
        self.timeout_s = timeout_s
        self.retry_s = retry_s
        self.limits = HostLimits.from_env() if limits is None else limits
        if transport is None:
            # Small PATCHes go out as headers and body: without TCP_NODELAY, Nagle's
            # algorithm and the server's delayed ACK add 40 ms to each.
            transport = httpx.HTTPTransport(socket_options=_NODELAY)
        self._http = httpx.Client(
            base_url=self.url + API, headers=headers, timeout=timeout_s, transport=transport
        )

    def close(self) -> None:
        self._http.close()

    # -- plumbing --------------------------------------------------------------------------

    def _error(self, method: str, path: str, status: int, content: bytes) -> CameraHTTPError:
        try:
            body = strict_json.loads(content, what="", limit_bytes=self.limits.json_bytes)
            if not isinstance(body, dict):
                body = {"detail": body}
        except ValueError:
            body = {"detail": content.decode("utf-8", errors="replace")}
        detail = shown(body.get("detail", body))
        message = f"{method} {path}: HTTP {status}: {detail}"
        kind = CameraUnauthorizedError if status in (401, 403) else CameraHTTPError
        return kind(message, status=status, body=body)

    def _read(
        self, response: httpx.Response, deadline: Deadline, limit_bytes: int, limit_name: str
    ) -> bytes:
        """The whole body of ``response`` within ``limit_bytes`` and ``deadline``."""
        what = deadline.what
        check_declared(
            response.headers.get("content-length"),
            limit_bytes=limit_bytes,
            what=what,
            limit_name=limit_name,
        )
        return read_bounded(
            response.iter_bytes(),
            limit_bytes=limit_bytes,
            deadline=deadline,
            what=what,
            limit_name=limit_name,
        )

    def _request(
        self,
        method: str,
        path: str,
        *,
        limit_bytes: int | None = None,
        limit_name: str = "json_bytes",
        deadline_s: float | None = None,
        **kwargs: Any,
    ) -> tuple[httpx.Response, bytes]:
        """Send a request; its answer and body, read within a size limit and an overall deadline."""
        limit = self.limits.json_bytes if limit_bytes is None else limit_bytes
        backoff = Backoff(self.retry_s)
        while True:
            deadline = Deadline(deadline_s or self.limits.deadline_s, what=self._what(method, path))
            timeout = min(self.timeout_s, deadline.seconds)
            try:
                with self._http.stream(method, path, timeout=timeout, **kwargs) as response:
                    if response.status_code >= 400:
                        content = self._read(
                            response, deadline, self.limits.json_bytes, "json_bytes"
                        )
                        raise self._error(method, path, response.status_code, content)
                    return response, self._read(response, deadline, limit, limit_name)
            except httpx.TransportError as e:
                if retryable(method, e) and backoff.wait():
                    continue
                raise CameraClientError(f"cannot reach the camera at {self.url}: {e}") from e
            except httpx.HTTPError as e:
                raise CameraClientError(f"cannot reach the camera at {self.url}: {e}") from e

    def _json(self, method: str, path: str, **kwargs: Any) -> Any:
        _, content = self._request(method, path, **kwargs)
        what = f"the camera at {self.url} ({method} {path})"
        return strict_json.loads(content, what=what, limit_bytes=self.limits.json_bytes)

    def _what(self, method: str, path: str) -> str:
        return f"the camera at {self.url} ({method} {path})"

    # -- board -----------------------------------------------------------------------------

    def info(self) -> dict[str, Any]:
        """Board, daemon version and ports with their sensors.

        The first thing a command asks, so it also tells a wrong URL apart: a server
        without the API (HTTP 404), or a port that does not answer HTTP within
        `INFO_TIMEOUT_S` (or the deadline, when shorter), raises `CameraClientError` saying
        which URL to give.
        """
        probe_s = min(INFO_TIMEOUT_S, self.limits.deadline_s)
        try:
            answer = self._json("GET", "/info", deadline_s=probe_s)
            result: dict[str, Any] = checked_dict(
                InfoAnswer, answer, what=self._what("GET", "/info")
            )
        except CameraHTTPError as e:
            if e.status != 404:
                raise
            raise CameraClientError(
                f"{self.url} is not elphel-camd (GET {API}/info: HTTP 404): give the daemon's "
                "http://HOST:PORT (elphel-sim up prints it as camera_url, not sim_url)"
            ) from e
        except CameraClientError as e:
            if not isinstance(e.__cause__, httpx.ReadTimeout):
                raise
            raise CameraClientError(
                f"{self.url} gave no HTTP answer within {probe_s:g} s: is it "
                "elphel-camd's port (not the stage's, nor another service's)?"
            ) from e
        return result

    def health(self) -> dict[str, Any]:
        """The daemon's health report; ``status`` is ``degraded`` when a bus fails (503)."""
        try:
            result = self._json("GET", "/health")
        except CameraHTTPError as e:
            if e.status != 503:
                raise
            result = e.body
        if not isinstance(result, dict):
            raise DeviceAnswerError(
                f"{self._what('GET', '/health')}: {shown(result, limit_chars=60)}; "
                "allowed: a JSON object"
            )
        return result

    # -- parameters ------------------------------------------------------------------------

    def params(self, port: int = 0, *, frame: int | None = None) -> dict[str, int]:
        """Parameters in effect now (or for a recent or scheduled frame)."""
        query = {} if frame is None else {"frame": frame}
        result: dict[str, int] = self._json("GET", f"/ports/{port}/params", params=query)
        return result

    def _set_params(
        self, changes: Mapping[str, int], port: int, frame: int | None, ahead: int | None
    ) -> Applied:
        """Change parameters all-or-nothing, at once, at frame ``frame`` or ``ahead`` frames on.

        Raises `CameraHTTPError` naming the parameter, value and allowed range: 422 when the
        schema refuses the value, 409 when the port's sensor or schedule does.
        """
        query: dict[str, Any] = {}
        if frame is not None:
            query["frame"] = str(frame)
        if ahead is not None:
            query["ahead"] = ahead
        path = f"/ports/{port}/params"
        body = self._json("PATCH", path, params=query, json=dict(changes))
        answer = checked(PatchAnswer, body, what=self._what("PATCH", path))
        return Applied(frame=answer.frame, params=dict(answer.params))

    def frame(self, port: int = 0) -> dict[str, int]:
        """Current frame number and its start time (ns)."""
        path = f"/ports/{port}/frame"
        result: dict[str, int] = checked_dict(
            FrameAnswer, self._json("GET", path), what=self._what("GET", path)
        )
        return result

    # -- frames ----------------------------------------------------------------------------

    def capture(self, port: int = 0, *, frame: int | None = None) -> CapturedFrame:
        """The next frame of a port, or frame ``frame`` from the daemon's ring buffer.

        A capture may take longer than ``timeout_s`` on a busy machine (the frame's image
        is still being formed): its wait follows the daemon's progress (`_capture_answer`).
        """
        query = {} if frame is None else {"frame": frame}
        path = f"/ports/{port}/capture"
        content = self._capture_answer(port, query)
        what = self._what("POST", path)
        image, metadata = read_tiff_metadata(content, limits=self.limits, what=what)
        checked(FrameMetadata, metadata, what=f"{what}, frame metadata")
        return CapturedFrame(tiff=content, image=image, metadata=metadata)

    def _capture_answer(self, port: int, query: dict[str, Any]) -> bytes:
        """The answer to a capture, waited for while the daemon shows progress.

        A capture that brings no byte within ``timeout_s`` is asked again as long as the
        daemon answers ``GET /ports/{port}/frame`` with a frame number past the one it
        gave before the try (it runs and its frames come: the image is being formed, not
        lost), at most `CAPTURE_TRIES` times. A daemon that does not answer, or whose
        frames stand still, ends the wait with the read timeout's error.
        """
        path = f"/ports/{port}/capture"
        limit = self.limits.frame_bytes + self.limits.json_bytes
        for tries in range(1, CAPTURE_TRIES + 1):
            before = self._frame_number(port)
            try:
                _, content = self._request(
                    "POST", path, params=query, limit_bytes=limit, limit_name="frame_pixels"
                )
                return content
            except CameraClientError as e:
                if tries == CAPTURE_TRIES or not self._still_forming(e.__cause__, port, before):
                    raise
        raise AssertionError("unreachable: the last try returns or raises")

    def _still_forming(self, error: BaseException | None, port: int, before: int | None) -> bool:
        """Whether a capture that timed out is worth asking again: the daemon's frames moved."""
        if not isinstance(error, httpx.ReadTimeout) or before is None:
            return False
        after = self._frame_number(port)
        return after is not None and after > before

    def _frame_number(self, port: int) -> int | None:
        """The port's current frame number, or None if the daemon does not answer it."""
        try:
            return int(self._json("GET", f"/ports/{port}/frame")["frame"])
        except (CameraClientError, DeviceAnswerError, DeviceLimitError, DeviceTimeout):
            return None
        except (ValueError, KeyError, TypeError):
            return None

    def burst(self, count: int, *, port: int = 0, frame: int | None = None) -> CapturedBurst:
        """``count`` consecutive frames (from the next one or from ``frame``) in one TIFF.

        The daemon sends every frame or breaks the connection off; a burst that ends
        early raises `PartialBurstError`, whose ``partial`` keeps the frames received.
        """
        if not 1 <= count <= self.limits.burst_frames:
            raise DeviceLimitError(
                f"count={count}; allowed: 1..{self.limits.burst_frames} "
                "(limit burst_frames; raise ELPHEL_LIMIT_BURST_FRAMES)"
            )
        query: dict[str, Any] = {"count": count}
        if frame is not None:
            query["frame"] = frame
        path = f"/ports/{port}/capture"
        data, broken = self._burst_bytes(path, query, count)
        if broken is None:
            try:
                what = self._what("POST", path)
                images, metadata = read_tiff_pages(data, limits=self.limits, what=what)
                for meta in metadata:
                    checked(FrameMetadata, meta, what=f"{what}, frame metadata")
            except (DeviceLimitError, DeviceAnswerError):
                raise
            except (ValueError, KeyError, OSError) as e:
                broken = f"unreadable TIFF: {shown(e, limit_chars=120)}"
            else:
                if len(metadata) == count:
                    return CapturedBurst(tiff=data, images=images, metadata=metadata)
                broken = f"the TIFF has {len(metadata)} pages"
        pages, metadata = read_partial_tiff(data, limits=self.limits)
        partial = CapturedBurst(
            tiff=_pages_tiff(pages, metadata), images=pages, metadata=metadata, complete=False
        )
        raise PartialBurstError(
            f"burst ended after {len(metadata)} of {count} frames ({broken}; see the daemon log)",
            partial=partial,
        )

    def _burst_bytes(
        self, path: str, query: dict[str, Any], count: int
    ) -> tuple[bytes, str | None]:
        """The bytes of a multi-frame capture and, if it broke off, why."""
        limits = self.limits
        deadline = Deadline(
            limits.deadline_s + count * limits.frame_deadline_s,
            what=self._what("POST", f"{path}?count={count}"),
        )
        limit = count * limits.frame_bytes + limits.json_bytes
        data = bytearray()
        backoff = Backoff(self.retry_s)
        tries = 1
        while True:
            timeout = min(self.timeout_s, deadline.seconds)
            before = self._frame_number(int(path.split("/")[2]))
            try:
                with self._http.stream("POST", path, params=query, timeout=timeout) as response:
                    if response.status_code >= 400:
                        content = self._read(response, deadline, limits.json_bytes, "json_bytes")
                        raise self._error("POST", path, response.status_code, content)
                    check_declared(
                        response.headers.get("content-length"),
                        limit_bytes=limit,
                        what=self._what("POST", path),
                        limit_name="frame_pixels",
                    )
                    read_bounded(
                        response.iter_bytes(),
                        limit_bytes=limit,
                        deadline=deadline,
                        what=self._what("POST", path),
                        limit_name="frame_pixels",
                        into=data,
                    )
            except httpx.TransportError as e:
                if not data and retryable("POST", e) and backoff.wait():
                    continue
                port = int(path.split("/")[2])
                if not data and tries < CAPTURE_TRIES and self._still_forming(e, port, before):
                    tries += 1
                    continue
                if not data:
                    raise CameraClientError(f"cannot reach the camera at {self.url}: {e}") from e
                return bytes(data), str(e) or type(e).__name__
            return bytes(data), None

    # -- raw registers ---------------------------------------------------------------------

    def registers(self, port: int = 0) -> list[dict[str, Any]]:
        """The sensor's register table."""
        result: list[dict[str, Any]] = self._json("GET", f"/ports/{port}/registers")
        return result

    def register(self, address: int, *, port: int = 0) -> dict[str, Any]:
        """Read a raw register now: name, address, value, limits."""
        result: dict[str, Any] = self._json("GET", f"/ports/{port}/registers/0x{address:x}")
        return result

    def set_register(self, address: int, value: int, *, port: int = 0) -> dict[str, Any]:
        """Write a raw register (checked against the register table by the daemon)."""
        result: dict[str, Any] = self._json(
            "PUT", f"/ports/{port}/registers/0x{address:x}", json={"value": value}
        )
        return result

    # -- events ----------------------------------------------------------------------------

    def events(
        self,
        types: tuple[str, ...] = ("frame", "params", "error"),
        *,
        port: int | None = None,
        count: int | None = None,
        reconnect: bool = True,
        last_id: int | None = None,
    ) -> Iterator[CameraEvent]:
        """Follow the daemon's events; stops after ``count`` events (else when closed).

        With ``reconnect`` a stream that ends or breaks (a daemon restart, a client that
        fell behind) is opened again with ``Last-Event-ID``, so the daemon replays what
        was missed; events it could not replay are announced by a ``dropped`` event.
        Gives up (`CameraClientError`) after ``retry_s`` without a connection.
        ``last_id`` resumes after that event id.
        """
        remaining = count
        backoff = Backoff(self.retry_s)
        while True:
            query = _event_query(types, port=port, count=remaining)
            headers = {} if last_id is None else {"Last-Event-ID": str(last_id)}
            # The daemon sends a keepalive comment every keepalive_s: silence for longer
            # than a few of them is a dead stream, not a quiet camera.
            timeout = httpx.Timeout(self.timeout_s, read=self.limits.event_read_timeout_s)
            try:
                with self._http.stream(
                    "GET", "/events", params=query, headers=headers, timeout=timeout
                ) as response:
                    if response.status_code >= 400:
                        deadline = Deadline(
                            self.limits.deadline_s, what=self._what("GET", "/events")
                        )
                        content = self._read(
                            response, deadline, self.limits.json_bytes, "json_bytes"
                        )
                        if response.status_code == 503 and reconnect and backoff.wait():
                            continue
                        raise self._error("GET", "/events", response.status_code, content)
                    backoff.reset()
                    for event in self._parsed_events(response):
                        if event.id is not None:
                            last_id = event.id
                        yield event
                        if event.type != "dropped" and remaining is not None:
                            remaining -= 1
                            if remaining == 0:
                                return
            except httpx.ReadTimeout as e:
                # A daemon that restarts closes the stream; one that stays silent past its
                # keepalives is broken, and reconnecting would only wait again.
                raise DeviceTimeout(
                    f"the event stream of the camera at {self.url} was silent for "
                    f"{self.limits.event_read_timeout_s:g} s (3 keepalive periods; "
                    "ELPHEL_LIMIT_KEEPALIVE_S sets the period)"
                ) from e
            except httpx.TransportError as e:
                if not (reconnect and backoff.wait()):
                    raise CameraClientError(f"event stream from {self.url} broke: {e}") from e
                continue
            except httpx.HTTPError as e:
                raise CameraClientError(f"event stream from {self.url} broke: {e}") from e
            if not reconnect:
                return
            if not backoff.wait():
                raise CameraClientError(
                    f"event stream from {self.url} ended and could not be reopened "
                    f"in {self.retry_s} s"
                )

    def _parsed_events(self, response: httpx.Response) -> Iterator[CameraEvent]:
        """The events of an open stream, each line and event within the limits, checked."""
        what = f"the event stream of the camera at {self.url}"
        parser = SSEParser(limit_bytes=self.limits.event_bytes, what=what)
        lines = bounded_lines(
            response.iter_bytes(), limit_bytes=self.limits.event_line_bytes, what=what
        )
        for line in lines:
            event = parser.feed(line)
            if event is None:
                continue
            model = EVENT_MODELS.get(event.type)
            if model is not None:
                checked(model, event.data, what=f"{what}, event {event.type!r} (id {event.id})")
            yield event


#: How many times a capture is sent while the daemon shows progress (`_capture_answer`).
CAPTURE_TRIES = 8


def _pages_tiff(pages: list[Any], metadata: list[dict[str, Any]]) -> bytes:
    """A multi-page TIFF of pages with their JSON metadata, as the daemon lays them out."""
    import io

    import tifffile

    buffer = io.BytesIO()
    with tifffile.TiffWriter(buffer) as tif:
        for image, meta in zip(pages, metadata, strict=True):
            tif.write(image, description=strict_json.dumps(meta, what="metadata"), metadata=None)
    return buffer.getvalue()


def _event_query(types: tuple[str, ...], *, port: int | None, count: int | None) -> dict[str, Any]:
    """The query of ``GET /events``: the types, and the port and count when given."""
    query: dict[str, Any] = {"types": ",".join(types)}
    if port is not None:
        query["port"] = port
    if count is not None:
        query["count"] = count
    return query
