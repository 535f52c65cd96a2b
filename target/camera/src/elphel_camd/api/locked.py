"""Short work under a port's locks, on the event loop when the locks are free.

A plain FastAPI route (``def``) runs in a worker thread. For the parameter routes that
costs more than the work: they hold a port's lock for tens of microseconds, and handing
each request to a thread and back under load (bench/load.py, 50 clients) took the time
in the app from 0.7 ms to 4.5 ms at the median, and to 40-90 ms at the 99th percentile.
`run_locked` does the work on the event loop instead, but only when every lock can be
taken at once: a lock held elsewhere (a frame sync programming the sensor, which waits
for the I2C bus) or work that waits for a device or a disk (``on_loop=False``) goes to a
worker thread as before, so the event loop never waits for either.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from types import TracebackType
from typing import Protocol, TypeVar

from starlette.concurrency import run_in_threadpool

T = TypeVar("T")


class Lock(Protocol):
    """`threading.Lock` or `threading.RLock`."""

    def acquire(self, blocking: bool = ..., timeout: float = ...) -> bool: ...

    def release(self) -> None: ...

    def __enter__(self) -> bool: ...

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
        /,
    ) -> None: ...


async def run_locked(locks: Sequence[Lock], work: Callable[[], T], *, on_loop: bool = True) -> T:
    """``work()`` holding ``locks`` (taken in their order, released in reverse)."""
    if on_loop:
        taken: list[Lock] = []
        try:
            for lock in locks:
                if not lock.acquire(blocking=False):
                    break
                taken.append(lock)
            else:
                return work()
        finally:
            for lock in reversed(taken):
                lock.release()

    def in_thread() -> T:
        with contextlib.ExitStack() as held:
            for lock in locks:
                held.enter_context(lock)
            return work()

    return await run_in_threadpool(in_thread)
