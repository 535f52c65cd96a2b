"""Short work under a port's locks, on the event loop when the locks are free.

A plain FastAPI route (``def``) runs in a worker thread. The parameter routes hold a
port's lock for tens of microseconds, less than the hand-off of a request to a thread
and back, which also queues behind other requests under load. `run_locked` does the work
on the event loop instead, when it can take every lock at once without blocking. A lock
held elsewhere (a frame sync programming the sensor holds its port's lock for a fraction
of a millisecond, on a slow I2C bus for a few) is tried again every `RETRY_S` while the
event loop serves other requests; only a lock still held after `LOOP_WAIT_S`, or work
that waits for a device or a disk (``on_loop=False``), goes to a worker thread, so the
event loop never blocks on either.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable, Sequence
from types import TracebackType
from typing import Protocol, TypeVar

from starlette.concurrency import run_in_threadpool

T = TypeVar("T")

#: How long work waits on the event loop for its locks before it goes to a worker thread.
LOOP_WAIT_S = 0.02
#: Pause between tries to take the locks.
RETRY_S = 0.001


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
        deadline = asyncio.get_running_loop().time() + LOOP_WAIT_S
        while True:
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
            if asyncio.get_running_loop().time() >= deadline:
                break
            await asyncio.sleep(RETRY_S)

    def in_thread() -> T:
        with contextlib.ExitStack() as held:
            for lock in locks:
                held.enter_context(lock)
            return work()

    return await run_in_threadpool(in_thread)
