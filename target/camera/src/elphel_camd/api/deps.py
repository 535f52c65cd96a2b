"""What the routes are given: the camera service, the API options, the bearer-token checks.

`create_app` puts the service on ``app.state.service`` and the `ApiOptions` on
``app.state.options``; the routes receive them through FastAPI dependencies (`Service`,
`Options`) and are guarded by `WRITES` (the token) or `READS` (the token unless the daemon
was started with public reads). `PortPath` and `FrameQuery` are the path and query
parameters the port routes share.

A wrong token is logged with the peer's address and answered after a delay that doubles
with each failure of that peer (`FailedAuth`, bounded), so guessing tokens over the
network is slow; the answer is the same whatever the token was. A missing token (no
guess) is logged and answered at once.
"""

from __future__ import annotations

import asyncio
import logging
import os
import secrets
import threading
import time
from collections import OrderedDict
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
    """

    token: TokenSource
    public_reads: bool = False
    keepalive_s: float = 15.0
    failed: FailedAuth = field(default_factory=FailedAuth)


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


def token_accepted(options: ApiOptions, given: str, peer: str) -> bool:
    """Whether ``given`` is the daemon's token; a right one clears ``peer``'s failures.

    Every token check goes through here: the routes' `require_token` and the parameter
    fast path (`elphel_camd.api.fast_path`).
    """
    # compare_digest on bytes of any length: no early exit that would tell how close it was.
    if given and secrets.compare_digest(given.encode(), options.token.current().encode()):
        options.failed.succeed(peer)
        return True
    return False


async def require_token(
    request: Request,
    options: Options,
    credentials: HTTPAuthorizationCredentials | None = _BEARER,
) -> None:
    """401 unless the request carries the daemon's bearer token (slowed per failing peer)."""
    given = credentials.credentials if credentials is not None else ""
    peer = _peer(request)
    if token_accepted(options, given, peer):
        return
    if given:
        # A guess: slowed down, more for each failure of the same peer.
        count, delay = options.failed.fail(peer)
        log.warning(
            "%s %s from %s: wrong token (failure %d of this peer; answering in %.2f s)",
            request.method,
            request.url.path,
            peer,
            count,
            delay,
        )
        await asyncio.sleep(delay)
    else:
        log.info("%s %s from %s: no token", request.method, request.url.path, peer)
    raise StarletteHTTPException(
        status_code=401,
        detail="this request needs the camera's token: send Authorization: Bearer <token>",
        headers={"WWW-Authenticate": "Bearer"},
    )


async def require_read(
    request: Request,
    options: Options,
    credentials: HTTPAuthorizationCredentials | None = _BEARER,
) -> None:
    """The token check, unless the daemon serves reads publicly."""
    if not options.public_reads:
        await require_token(request, options, credentials)


WRITES = [Depends(require_token)]
READS = [Depends(require_read)]

PortPath = Annotated[int, PathParam(ge=0, le=0x7FFFFFFF, description="sensor port (0..3 on NC393)")]
FrameQuery = Annotated[int | None, Query(ge=0, le=0x7FFFFFFF, description="frame number")]
