"""Typed REST client of elphel-camd (docs/rest-api.md).

What it decodes lives next to it: frames and multi-page bursts in
:mod:`elphel_host.camera.frames`, the event stream in :mod:`elphel_host.camera.events`.
When a failed request is sent again is :mod:`elphel_host.camera.retry`'s policy.
"""

from __future__ import annotations

import json
import socket
from collections.abc import Iterator, Mapping
from typing import Any

import httpx

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
from elphel_host.errors import CameraAuthError, CameraClientError

API = "/api/v1"
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
        Per-request timeout.
    retry_s
        How long to keep retrying while the daemon cannot be reached (a restart): reads
        and other idempotent requests are retried after any connection failure, PATCH
        and capture only when the connection could not be made (so a change is never
        applied twice); the event stream reconnects with the last event id it got. 0
        gives up at once.
    transport
        httpx transport to use instead of the network (tests).

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
    ) -> None:
        if not url.startswith(("http://", "https://")):
            raise ValueError(f"camera url {url!r}; allowed: http://HOST:PORT or https://...")
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.url = url.rstrip("/")
        self.timeout_s = timeout_s
        self.retry_s = retry_s
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

    def _error(self, method: str, path: str, response: httpx.Response) -> CameraHTTPError:
        try:
            body = response.json()
            if not isinstance(body, dict):
                body = {"detail": body}
        except (json.JSONDecodeError, UnicodeDecodeError):
            body = {"detail": response.text}
        message = f"{method} {path}: HTTP {response.status_code}: {body.get('detail', body)}"
        kind = CameraUnauthorizedError if response.status_code in (401, 403) else CameraHTTPError
        return kind(message, status=response.status_code, body=body)

    def _request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        backoff = Backoff(self.retry_s)
        while True:
            try:
                response = self._http.request(method, path, **kwargs)
            except httpx.TransportError as e:
                if retryable(method, e) and backoff.wait():
                    continue
                raise CameraClientError(f"cannot reach the camera at {self.url}: {e}") from e
            except httpx.HTTPError as e:
                raise CameraClientError(f"cannot reach the camera at {self.url}: {e}") from e
            if response.status_code >= 400:
                raise self._error(method, path, response)
            return response

    def _json(self, method: str, path: str, **kwargs: Any) -> Any:
        return self._request(method, path, **kwargs).json()

    # -- board -----------------------------------------------------------------------------

    def info(self) -> dict[str, Any]:
        """Board, daemon version and ports with their sensors."""
        result: dict[str, Any] = self._json("GET", "/info")
        return result

    def health(self) -> dict[str, Any]:
        """The daemon's health report; ``status`` is ``degraded`` when a bus fails (503)."""
        try:
            response = self._http.get("/health")
        except httpx.HTTPError as e:
            raise CameraClientError(f"cannot reach the camera at {self.url}: {e}") from e
        if response.status_code not in (200, 503):
            raise self._error("GET", "/health", response)
        result: dict[str, Any] = response.json()
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
        body = self._json("PATCH", f"/ports/{port}/params", params=query, json=dict(changes))
        return Applied(frame=int(body["frame"]), params=dict(body["params"]))

    def frame(self, port: int = 0) -> dict[str, int]:
        """Current frame number and its start time (ns)."""
        result: dict[str, int] = self._json("GET", f"/ports/{port}/frame")
        return result

    # -- frames ----------------------------------------------------------------------------

    def capture(self, port: int = 0, *, frame: int | None = None) -> CapturedFrame:
        """The next frame of a port, or frame ``frame`` from the daemon's ring buffer.

        A capture may take longer than ``timeout_s`` on a busy machine (the frame's image
        is still being formed): its wait follows the daemon's progress (`_capture_answer`).
        """
        query = {} if frame is None else {"frame": frame}
        response = self._capture_answer(port, query)
        image, metadata = read_tiff_metadata(response.content)
        return CapturedFrame(tiff=response.content, image=image, metadata=metadata)

    def _capture_answer(self, port: int, query: dict[str, Any]) -> httpx.Response:
        """The answer to a capture, waited for while the daemon shows progress.

        A capture that brings no byte within ``timeout_s`` is asked again as long as the
        daemon answers ``GET /ports/{port}/frame`` with a frame number past the one it
        gave before the try (it runs and its frames come: the image is being formed, not
        lost), at most `CAPTURE_TRIES` times. A daemon that does not answer, or whose
        frames stand still, ends the wait with the read timeout's error.
        """
        path = f"/ports/{port}/capture"
        for _ in range(CAPTURE_TRIES - 1):
            before = self._frame_number(port)
            try:
                return self._request("POST", path, params=query)
            except CameraClientError as e:
                if not self._still_forming(e.__cause__, port, before):
                    raise
        return self._request("POST", path, params=query)

    def _still_forming(self, error: BaseException | None, port: int, before: int | None) -> bool:
        """Whether a capture that timed out is worth asking again: the daemon's frames moved."""
        if not isinstance(error, httpx.ReadTimeout) or before is None:
            return False
        after = self._frame_number(port)
        return after is not None and after > before

    def _frame_number(self, port: int) -> int | None:
        """The port's current frame number, or None if the daemon does not answer it."""
        try:
            return int(self._http.get(f"/ports/{port}/frame").json()["frame"])
        except (httpx.HTTPError, ValueError, KeyError, TypeError):
            return None

    def burst(self, count: int, *, port: int = 0, frame: int | None = None) -> CapturedBurst:
        """``count`` consecutive frames (from the next one or from ``frame``) in one TIFF.

        The daemon sends every frame or breaks the connection off; a burst that ends
        early raises `PartialBurstError`, whose ``partial`` keeps the frames received.
        A burst whose first bytes do not come within ``timeout_s`` is waited for as a
        single capture is (`_capture_answer`).
        """
        query: dict[str, Any] = {"count": count}
        if frame is not None:
            query["frame"] = frame
        path = f"/ports/{port}/capture"
        data = bytearray()
        broken: str | None = None
        backoff = Backoff(self.retry_s)
        tries = 1
        while True:
            before = self._frame_number(port)
            try:
                with self._http.stream("POST", path, params=query) as response:
                    if response.status_code >= 400:
                        response.read()
                        raise self._error("POST", path, response)
                    for chunk in response.iter_bytes():
                        data += chunk
            except httpx.TransportError as e:
                if not data and retryable("POST", e) and backoff.wait():
                    continue
                if not data and tries < CAPTURE_TRIES and self._still_forming(e, port, before):
                    tries += 1
                    continue
                if not data:
                    raise CameraClientError(f"cannot reach the camera at {self.url}: {e}") from e
                broken = str(e) or type(e).__name__
            break
        if broken is None:
            try:
                images, metadata = read_tiff_pages(bytes(data))
            except (ValueError, KeyError, OSError, json.JSONDecodeError) as e:
                broken = f"unreadable TIFF: {e}"
            else:
                if len(metadata) == count:
                    return CapturedBurst(tiff=bytes(data), images=images, metadata=metadata)
                broken = f"the TIFF has {len(metadata)} pages"
        pages, metadata = read_partial_tiff(bytes(data))
        partial = CapturedBurst(
            tiff=_pages_tiff(pages, metadata), images=pages, metadata=metadata, complete=False
        )
        raise PartialBurstError(
            f"burst ended after {len(metadata)} of {count} frames ({broken}; see the daemon log)",
            partial=partial,
        )

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
            timeout = httpx.Timeout(self.timeout_s, read=None)
            try:
                with self._http.stream(
                    "GET", "/events", params=query, headers=headers, timeout=timeout
                ) as response:
                    if response.status_code >= 400:
                        response.read()
                        if response.status_code == 503 and reconnect and backoff.wait():
                            continue
                        raise self._error("GET", "/events", response)
                    backoff.reset()
                    parser = SSEParser()
                    for line in response.iter_lines():
                        event = parser.feed(line)
                        if event is None:
                            continue
                        if event.id is not None:
                            last_id = event.id
                        yield event
                        if event.type != "dropped" and remaining is not None:
                            remaining -= 1
                            if remaining == 0:
                                return
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


#: How many times a single-frame capture is sent while the daemon shows progress.
CAPTURE_TRIES = 8


def _pages_tiff(pages: list[Any], metadata: list[dict[str, Any]]) -> bytes:
    """A multi-page TIFF of pages with their JSON metadata, as the daemon lays them out."""
    import io

    import tifffile

    buffer = io.BytesIO()
    with tifffile.TiffWriter(buffer) as tif:
        for image, meta in zip(pages, metadata, strict=True):
            tif.write(image, description=json.dumps(meta), metadata=None)
    return buffer.getvalue()


def _event_query(types: tuple[str, ...], *, port: int | None, count: int | None) -> dict[str, Any]:
    """The query of ``GET /events``: the types, and the port and count when given."""
    query: dict[str, Any] = {"types": ",".join(types)}
    if port is not None:
        query["port"] = port
    if count is not None:
        query["count"] = count
    return query
