"""What the routes are given: the camera service, the API options, the bearer-token checks.

`create_app` puts the service on ``app.state.service`` and the `ApiOptions` on
``app.state.options``; the routes receive them through FastAPI dependencies (`Service`,
`Options`) and are guarded by `WRITES` (the token) or `READS` (the token unless the daemon
was started with public reads). `PortPath` and `FrameQuery` are the path and query
parameters the port routes share.

A request carries the token in exactly one ``Authorization: Bearer`` header: two or more
``Authorization`` headers are refused like a wrong token (`token_accepted` is the one
rule, for the routes and the parameter fast path alike). A wrong token is logged with the
peer's address and answered after a delay that doubles with each failure of that peer
(`FailedAuth`, bounded), so guessing tokens over the network is slow; the answer is the
same whatever the token was. A missing token (no guess) is logged and answered at once.
These log lines are rate-limited (`LogLimit`): a flood of bad tokens cannot fill the disk.
"""

from __future__ import annotations

import asyncio
import logging
import os
import secrets
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

from fastapi import Depends, Query, Request
from fastapi import Path as PathParam
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.exceptions import HTTPException as StarletteHTTPException

from elphel_camd.service import CameraService

log = logging.getLogger("elphel_camd.auth")


class TokenSource:
    """The bearer token: a fixed string, or the token file, re-read when it changes.

    With a file, every check compares the file's identity (inode, size, modification
    time) with the one last read, a ``stat`` call; a file replaced by
    ``elphel-camd token rotate`` is read at the next request, so the old token is refused
    from then on without a restart. A file that became unreadable or empty keeps the
    last token and logs why.

    Parameters
    ----------
    token
        A fixed token (``--token``, ``ELPHEL_CAMD_TOKEN``), or None to read ``path``.
    path
        The token file.
    """

    def __init__(self, token: str | None = None, *, path: Path | None = None) -> None:
        if not token and path is None:
            raise ValueError("the API token must not be empty")
        self.path = path
        self._lock = threading.Lock()
        self._stamp: tuple[int, int, int] | None = None
        self._token = token or ""
        if not token:
            self._reload()
            if not self._token:
                raise ValueError(f"the token file {path} is empty")

    def _reload(self) -> None:
        assert self.path is not None
        try:
            st = os.stat(self.path)
            stamp = (st.st_ino, st.st_size, st.st_mtime_ns)
            if stamp == self._stamp:
                return
            text = self.path.read_text().strip()
        except OSError as e:
            log.error("cannot read the token file %s (keeping the last token): %s", self.path, e)
            return
        with self._lock:
            if text:
                if self._token and text != self._token:
                    log.info("token file %s changed: the new token is in effect", self.path)
                self._token = text
            else:
                log.error("token file %s is empty (keeping the last token)", self.path)
            self._stamp = stamp

    def current(self) -> str:
        """The token in effect now."""
        if self.path is not None:
            self._reload()
        return self._token


@dataclass
class FailedAuth:
    """Per-peer count of failed authentications and the delay of the next answer.

    The delay is ``base_s * 2**(failures - 1)``, at most ``max_s``; a success resets the
    peer. At most ``peers`` addresses are remembered (the least recent is forgotten).
    """

    base_s: float = 0.05
    max_s: float = 2.0
    peers: int = 1024
    _failures: OrderedDict[str, tuple[int, float]] = field(default_factory=OrderedDict)

    def fail(self, peer: str) -> tuple[int, float]:
        """Count a failure of ``peer``; its running count and the delay to answer after."""
        count = self._failures.pop(peer, (0, 0.0))[0] + 1
        self._failures[peer] = (count, time.monotonic())
        while len(self._failures) > self.peers:
            self._failures.popitem(last=False)
        return count, min(self.max_s, self.base_s * 2 ** min(count - 1, 30))

    def succeed(self, peer: str) -> None:
        self._failures.pop(peer, None)

    def failures(self, peer: str) -> int:
        return self._failures.get(peer, (0, 0.0))[0]


@dataclass
class LogLimit:
    """At most ``lines`` log lines per ``window_s``; the others are counted, not written.

    The next line written after some were left out says how many (`allow`).
    """

    lines: int = 10
    window_s: float = 60.0
    _times: deque[float] = field(default_factory=deque)
    _left_out: int = 0

    def allow(self) -> int | None:
        """None: leave this line out; else how many lines were left out before it."""
        now = time.monotonic()
        while self._times and self._times[0] <= now - self.window_s:
            self._times.popleft()
        if len(self._times) >= self.lines:
            self._left_out += 1
            return None
        self._times.append(now)
        left_out, self._left_out = self._left_out, 0
        return left_out


@dataclass
class ApiOptions:
    """How the API guards and streams (fixed when the app is built).

    Parameters
    ----------
    token
        Where the bearer token that writes (and reads, unless public) must carry comes from.
    public_reads
        Reads are answered without the token (writes still need it).
    keepalive_s
        Idle time after which the event stream sends a comment line.
    stream_idle_s
        An event stream with no event of its types for this long ends (keepalive comments
        do not count).
    failed
        The per-peer back-off of failed tokens.
    auth_log
        The rate limit of the failed-token log lines.
    """

    token: TokenSource
    public_reads: bool = False
    keepalive_s: float = 15.0
    stream_idle_s: float = 300.0
    failed: FailedAuth = field(default_factory=FailedAuth)
    auth_log: LogLimit = field(default_factory=LogLimit)


async def get_service(request: Request) -> CameraService:
    """The camera service the app was built for."""
    service: CameraService = request.app.state.service
    return service


async def get_options(request: Request) -> ApiOptions:
    """The options the app was built with."""
    options: ApiOptions = request.app.state.options
    return options


Service = Annotated[CameraService, Depends(get_service)]
Options = Annotated[ApiOptions, Depends(get_options)]

BEARER = HTTPBearer(auto_error=False, description="the daemon's token")
_BEARER = Depends(BEARER)


def _peer(request: Request) -> str:
    return request.client.host if request.client is not None else "unknown"


def bearer(headers: Iterable[tuple[bytes, bytes]]) -> tuple[int, str]:
    """How many ``Authorization`` headers an ASGI request has, and the bearer token of one.

    The token is "" unless there is exactly one such header and it says ``Bearer <token>``.
    """
    values = [value for key, value in headers if key.lower() == b"authorization"]
    if len(values) != 1:
        return len(values), ""
    scheme, _, given = values[0].decode("latin-1").strip().partition(" ")
    return 1, given.strip() if scheme.lower() == "bearer" else ""


def token_accepted(options: ApiOptions, headers: Iterable[tuple[bytes, bytes]], peer: str) -> bool:
    """Whether the request's one ``Authorization`` header bears the daemon's token.

    Every token check goes through here: the routes' `require_token` and the parameter
    fast path (`elphel_camd.api.fast_path`). Two or more ``Authorization`` headers are
    refused whatever they say. A right token clears ``peer``'s failures.
    """
    count, given = bearer(headers)
    # compare_digest on bytes of any length: no early exit that would tell how close it was.
    expected = options.token.current().encode()
    if count == 1 and given and secrets.compare_digest(given.encode(), expected):
        options.failed.succeed(peer)
        return True
    return False


def _log_refusal(options: ApiOptions, level: int, message: str, *args: object) -> None:
    """Log a refused token, unless the rate limit leaves the line out (then it is counted)."""
    left_out = options.auth_log.allow()
    if left_out is None:
        return
    if left_out:
        message += f" ({left_out} similar lines left out before this one)"
    log.log(level, message, *args)


_NO_TOKEN = "this request needs the camera's token: send Authorization: Bearer <token>"


async def require_token(
    request: Request,
    options: Options,
    _declared: HTTPAuthorizationCredentials | None = _BEARER,
) -> None:
    """401 unless the request carries the daemon's bearer token (slowed per failing peer).

    ``_declared`` only declares the bearer security in the OpenAPI schema; the check reads
    the request's headers itself (`token_accepted`).
    """
    headers = request.scope["headers"]
    peer = _peer(request)
    if token_accepted(options, headers, peer):
        return
    count, given = bearer(headers)
    where = (request.method, request.url.path, peer)
    detail = _NO_TOKEN
    if count > 1:
        detail = f"this request has {count} Authorization headers: send one (Bearer <token>)"
    if given or count > 1:
        # A guess: slowed down, more for each failure of the same peer.
        failures, delay = options.failed.fail(peer)
        why = "wrong token" if count == 1 else f"{count} Authorization headers"
        _log_refusal(
            options,
            logging.WARNING,
            "%s %s from %s: %s (failure %d of this peer; answering in %.2f s)",
            *where,
            why,
            failures,
            delay,
        )
        await asyncio.sleep(delay)
    else:
        _log_refusal(options, logging.INFO, "%s %s from %s: no token", *where)
    raise StarletteHTTPException(
        status_code=401, detail=detail, headers={"WWW-Authenticate": "Bearer"}
    )


async def require_read(
    request: Request,
    options: Options,
    _declared: HTTPAuthorizationCredentials | None = _BEARER,
) -> None:
    """The token check, unless the daemon serves reads publicly."""
    if not options.public_reads:
        await require_token(request, options, _declared)


WRITES = [Depends(require_token)]
READS = [Depends(require_read)]

PortPath = Annotated[int, PathParam(ge=0, le=0x7FFFFFFF, description="sensor port (0..3 on NC393)")]
FrameQuery = Annotated[int | None, Query(ge=0, le=0x7FFFFFFF, description="frame number")]
