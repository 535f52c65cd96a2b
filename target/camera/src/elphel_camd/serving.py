"""How the daemon's HTTP server runs: timeouts, connection limits, graceful shutdown.

uvicorn holds a connection as long as the client keeps it open: one that sends half a
request (or nothing) is kept forever, and a shutdown waits for every event stream to end.
Here:

- a request must arrive whole (head and body) within ``request_timeout_s`` of the
  connection opening or of the first byte after the previous answer, else the connection
  is closed (a slow or half-open client cannot hold a file descriptor for long);
- an idle keep-alive connection is closed after ``idle_timeout_s``;
- at most ``max_connections`` connections and requests are served at once (503 beyond);
- on SIGINT/SIGTERM the event streams are ended first (``on_shutdown``), and whatever is
  still running a second later is cancelled.
"""

from __future__ import annotations

import asyncio
import logging
import socket
from collections.abc import Callable, Sequence
from typing import Any

import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol

from elphel_camd.api.routes.events import CUT_EXTENSION, SEND_BUFFER_EXTENSION

log = logging.getLogger(__name__)

REQUEST_TIMEOUT_S = 10.0
IDLE_TIMEOUT_S = 5.0
SHUTDOWN_TIMEOUT_S = 1.0
MAX_CONNECTIONS = 512


class TimedH11Protocol(H11Protocol):
    """uvicorn's HTTP/1.1 protocol with a deadline for each request to arrive whole."""

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
    **options: Any,
) -> uvicorn.Config:
    """The uvicorn configuration of a daemon app with its timeouts and limits.

    ``options`` go to uvicorn as they are (TLS files, the header size limit).
    """
    protocol = type(
        "TimedH11Protocol", (TimedH11Protocol,), {"request_timeout_s": request_timeout_s}
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
        **options,
    )
