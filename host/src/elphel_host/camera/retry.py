"""The REST client's retry policy: which failed requests may be sent again, and the back-off.

`~elphel_host.camera.client.CameraClient` retries while the daemon cannot be reached (a
restart), within its ``retry_s`` budget.
"""

from __future__ import annotations

import time

import httpx

# Methods whose repetition changes nothing more than the first did.
IDEMPOTENT = frozenset({"GET", "HEAD", "OPTIONS", "PUT", "DELETE"})


def retryable(method: str, error: httpx.TransportError) -> bool:
    """Whether a request that failed so can be sent again safely.

    Idempotent requests after any transport failure except a read timeout (the daemon
    may be busy; waiting again would double the wait); others only when no connection
    was made, i.e. the daemon never saw the request.
    """
    if isinstance(error, httpx.ConnectError | httpx.ConnectTimeout):
        return True
    return method.upper() in IDEMPOTENT and not isinstance(error, httpx.ReadTimeout)


class Backoff:
    """Exponential back-off (50 ms doubling to 1 s) within a budget of ``total_s``."""

    def __init__(self, total_s: float) -> None:
        self.total_s = total_s
        self.reset()

    def reset(self) -> None:
        self.delay_s = 0.05
        self.started: float | None = None

    def wait(self) -> bool:
        """Sleep before the next try; False (no sleep) once the budget is spent."""
        now = time.monotonic()
        if self.started is None:
            self.started = now
        if now - self.started + self.delay_s > self.total_s:
            return False
        time.sleep(self.delay_s)
        self.delay_s = min(self.delay_s * 2, 1.0)
        return True
