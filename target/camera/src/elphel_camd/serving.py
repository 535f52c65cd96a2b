"""How the daemon's HTTP server runs: timeouts, connection limits, graceful shutdown.

uvicorn holds a connection as long as the client keeps it open: one that sends half a
request (or nothing) is kept forever, and a shutdown waits for every event stream to end.
Here:

- a request must arrive whole (head and body) within ``request_timeout_s`` of the
  connection opening or of the first byte after the previous answer, else the connection
  is closed (a slow or half-open client cannot hold a file descriptor for long);
- an idle keep-alive connection is closed after ``idle_timeout_s``;
- at most ``max_connections`` connections and requests are served at once (503 beyond);
- a request's line and headers may take at most ``max_head_bytes`` (400 and closed beyond);
- on SIGINT/SIGTERM the event streams are ended first (``on_shutdown``), and whatever is
  still running a second later is cancelled;
- every answer carries the headers every answer of the app carries
  (`elphel_camd.api.middleware.ANSWER_HEADERS`), those the server makes itself (400, 503,
  500) too.

HTTP is parsed by httptools (C) when it is installed, else by h11 (pure Python); all of
the above holds with either.
"""

from __future__ import annotations

import asyncio
import importlib.util
import logging
import socket
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol

from elphel_camd.api.middleware import ANSWER_HEADERS, SERVER_HEADERS_EXTENSION
from elphel_camd.api.routes.events import CUT_EXTENSION, SEND_BUFFER_EXTENSION

log = logging.getLogger(__name__)

REQUEST_TIMEOUT_S = 10.0
IDLE_TIMEOUT_S = 5.0
SHUTDOWN_TIMEOUT_S = 1.0
MAX_CONNECTIONS = 512
MAX_HEAD_BYTES = 16384


# The deadline is added to either of uvicorn's HTTP/1.1 protocols (they share the
# attributes it uses: loop, transport, client, cycle).
if TYPE_CHECKING:
    _Protocol = H11Protocol
else:
    _Protocol = object


class _RequestDeadline(_Protocol):
    """A deadline for each request to arrive whole, on one of uvicorn's protocols."""

    request_timeout_s = REQUEST_TIMEOUT_S

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._deadline: asyncio.TimerHandle | None = None
        self._arm()

    def _arm(self) -> None:
        if self._deadline is None:
            self._deadline = self.loop.call_later(self.request_timeout_s, self._too_slow)

    def _disarm(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _too_slow(self) -> None:
        self._deadline = None
        if not self.transport.is_closing():
            peer = f"{self.client[0]}:{self.client[1]}" if self.client else "a client"
            log.warning(
                "%s: request not complete after %.0f s: closed", peer, self.request_timeout_s
            )
            self.transport.abort()

    def data_received(self, data: bytes) -> None:
        cycle_before = self.cycle
        super().data_received(data)
        cycle = self.cycle
        if cycle is not None and cycle is not cycle_before:
            # A new request: let its stream (events) cut the connection if it must.
            extensions: Any = cycle.scope.setdefault("extensions", {})
            extensions[CUT_EXTENSION] = self._cut
            extensions[SEND_BUFFER_EXTENSION] = self._limit_send_buffer
            # What this answer will carry anyway: the app's middleware need not add it.
            extensions[SERVER_HEADERS_EXTENSION] = frozenset(
                name.decode("latin-1") for name, _ in cycle.default_headers
            )
        waiting = cycle is None or cycle.response_complete or cycle.more_body
        if waiting and not self.transport.is_closing():
            self._arm()
        else:
            self._disarm()

    def _cut(self, grace_s: float) -> None:
        """Close this connection; drop it if what is buffered has not gone out in grace_s."""
        self.transport.close()
        self.loop.call_later(grace_s, self.transport.abort)

    def _limit_send_buffer(self, nbytes: int) -> None:
        """Fix this connection's send buffers: the kernel's and the transport's.

        Without it the kernel grows a stalled client's buffer up to 4 MiB.
        """
        sock = self.transport.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, nbytes)
        self.transport.set_write_buffer_limits(high=nbytes)

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        super().connection_lost(exc)


class TimedH11Protocol(_RequestDeadline, H11Protocol):
    """uvicorn's pure-Python HTTP/1.1 protocol (h11) with the request deadline."""

    parser_name = "h11"

    def send_400_response(self, msg: str) -> None:
        """Answer 400 and close, with the headers of every answer (uvicorn's h11 400 has none)."""
        body = msg.encode("ascii")
        lines = [b"HTTP/1.1 400 Bad Request"]
        lines += [name + b": " + value for name, value in self.server_state.default_headers]
        lines += [
            b"content-type: text/plain; charset=utf-8",
            b"content-length: %d" % len(body),
            b"connection: close",
        ]
        self.transport.write(b"\r\n".join(lines) + b"\r\n\r\n" + body)
        self.transport.close()


def _httptools_protocol() -> type[Any] | None:
    """The httptools protocol of uvicorn with the request deadline, if httptools imports.

    httptools parses HTTP in C: a request takes less of the daemon's CPU than with h11.
    """
    try:
        from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol
    except ImportError:
        return None

    class TimedHttpToolsProtocol(_RequestDeadline, HttpToolsProtocol):  # type: ignore[misc]
        """uvicorn's httptools protocol with the request deadline and a head size limit.

        h11 bounds a request's head itself; httptools does not: the bytes of each request's
        head are counted (up to its empty line: a body that arrives in the same read is
        not), and past ``max_head_bytes`` the connection is answered 400 and closed.
        """

        parser_name = "httptools"
        max_head_bytes = MAX_HEAD_BYTES

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            self._head_bytes = 0
            self._head_tail = b""  # the last bytes of the head so far (an end split in two)
            self._in_body = False

        def data_received(self, data: bytes) -> None:
            if not self._in_body:
                self._head_bytes += _head_part(self._head_tail, data)
                self._head_tail = (self._head_tail + data)[-3:]
                if self._head_bytes > self.max_head_bytes:
                    self._head_too_large()
                    return
            super().data_received(data)

        def _head_too_large(self) -> None:
            peer = f"{self.client[0]}:{self.client[1]}" if self.client else "a client"
            log.warning("%s: request head over %d bytes: closed", peer, self.max_head_bytes)
            self.send_400_response("Request head too large.")

        def on_headers_complete(self) -> None:
            self._head_bytes = 0
            self._head_tail = b""
            self._in_body = True
            super().on_headers_complete()

        def on_message_complete(self) -> None:
            self._in_body = False
            super().on_message_complete()

    return TimedHttpToolsProtocol


def _head_part(tail: bytes, data: bytes) -> int:
    """How many bytes of ``data`` belong to a request head whose last bytes were ``tail``.

    The head ends at its first empty line; what follows in the same read is the body
    (or the next pipelined request), which the head limit must not count.
    """
    end = (tail + data).find(b"\r\n\r\n")
    if end < 0:
        return len(data)
    return max(0, end + 4 - len(tail))


class GracefulServer(uvicorn.Server):
    """A uvicorn server that runs ``on_shutdown`` callbacks as soon as it starts stopping.

    Parameters
    ----------
    config
        The uvicorn configuration (see `server_config`).
    on_shutdown
        Called first on shutdown (e.g. ending the event streams).
    handle_signals
        False leaves SIGINT/SIGTERM to the caller (a launcher running several servers).
    """

    def __init__(
        self,
        config: uvicorn.Config,
        *,
        on_shutdown: Sequence[Callable[[], None]] = (),
        handle_signals: bool = True,
    ) -> None:
        super().__init__(config)
        self.on_shutdown = list(on_shutdown)
        self.handle_signals = handle_signals

    def capture_signals(self) -> Any:
        if self.handle_signals:
            return super().capture_signals()
        return _NoSignals()

    async def shutdown(self, sockets: list[Any] | None = None) -> None:
        for callback in self.on_shutdown:
            try:
                callback()
            except Exception:
                log.exception("shutdown callback failed")
        await super().shutdown(sockets)


class _NoSignals:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None


def server_config(
    app: Any,
    *,
    log_level: str = "info",
    access_log: bool = True,
    request_timeout_s: float = REQUEST_TIMEOUT_S,
    idle_timeout_s: float = IDLE_TIMEOUT_S,
    max_connections: int = MAX_CONNECTIONS,
    max_head_bytes: int = MAX_HEAD_BYTES,
    **options: Any,
) -> uvicorn.Config:
    """The uvicorn configuration of a daemon app with its timeouts and limits.

    HTTP is parsed by httptools when it is installed, else by h11; the event loop is
    uvloop's when installed (uvicorn's ``loop="auto"``). A request's line and headers
    are bounded by ``max_head_bytes`` with either parser. ``options`` go to uvicorn as
    they are (TLS files).
    """
    base = _httptools_protocol() or TimedH11Protocol
    protocol = type(
        base.__name__,
        (base,),
        {"request_timeout_s": request_timeout_s, "max_head_bytes": max_head_bytes},
    )
    return uvicorn.Config(
        app,
        http=protocol,
        log_level=log_level,
        access_log=access_log,
        lifespan="off",
        timeout_keep_alive=int(max(1, idle_timeout_s)),
        timeout_graceful_shutdown=int(max(1, SHUTDOWN_TIMEOUT_S)),
        limit_concurrency=max_connections,
        h11_max_incomplete_event_size=max_head_bytes,
        headers=list(ANSWER_HEADERS),
        **options,
    )


def http_stack(config: uvicorn.Config) -> str:
    """Which HTTP parser and event loop ``config`` serves with, e.g. "httptools, uvloop"."""
    parser = getattr(config.http, "parser_name", "h11")
    loop = config.loop
    if loop == "auto":
        loop = "uvloop" if importlib.util.find_spec("uvloop") is not None else "asyncio"
    return f"{parser}, {loop}"
