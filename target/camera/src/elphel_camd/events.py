"""Publish/subscribe of daemon events (frames, parameter changes, errors).

Publishers are the frame-sync thread and request handlers; they never wait. Each
subscriber has a bounded queue: when it is full the oldest event is dropped and counted,
so a slow client loses events but never slows acquisition down.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import threading
import time
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

EVENT_TYPES = ("frame", "params", "error")


@dataclass(frozen=True)
class Event:
    """One event: a sequence number, its type and a JSON-ready body."""

    id: int
    type: str
    data: dict[str, Any]


@dataclass
class Subscription:
    """One subscriber's bounded queue, filled by `EventHub.publish`.

    Wait for events with `get` (asyncio) or `get_blocking` (threads).
    """

    types: frozenset[str]
    port: int | None
    maxlen: int
    dropped: int = 0
    _queue: deque[Event] = field(default_factory=deque)
    _cond: threading.Condition = field(default_factory=threading.Condition)
    _loop: asyncio.AbstractEventLoop | None = None
    _wakeup: asyncio.Event | None = None

    def wants(self, event: Event) -> bool:
        if event.type not in self.types:
            return False
        return self.port is None or event.data.get("port", self.port) == self.port

    def _put(self, event: Event) -> None:
        with self._cond:
            if len(self._queue) >= self.maxlen:
                self._queue.popleft()
                self.dropped += 1
            self._queue.append(event)
            self._cond.notify()
        if self._loop is not None and self._wakeup is not None:
            # RuntimeError: the client's loop is gone; the client unsubscribes on its way out.
            with contextlib.suppress(RuntimeError):
                self._loop.call_soon_threadsafe(self._wakeup.set)

    def _pop(self) -> Event | None:
        with self._cond:
            return self._queue.popleft() if self._queue else None

    async def get(self, timeout_s: float) -> Event | None:
        """The next event, or None after ``timeout_s`` without one."""
        if self._wakeup is None:
            self._loop = asyncio.get_running_loop()
            self._wakeup = asyncio.Event()
        event = self._pop()
        if event is not None:
            return event
        self._wakeup.clear()
        event = self._pop()  # published between the first look and clear()
        if event is not None:
            return event
        try:
            await asyncio.wait_for(self._wakeup.wait(), timeout_s)
        except TimeoutError:
            return None
        return self._pop()

    def get_blocking(self, timeout_s: float) -> Event | None:
        """The next event, waiting in this thread up to ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while not self._queue:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self._cond.wait(remaining)
            return self._queue.popleft()


class EventHub:
    """Fan-out of events to subscribers.

    Parameters
    ----------
    queue_size
        Events kept per subscriber before the oldest are dropped.
    """

    def __init__(self, queue_size: int = 256) -> None:
        self.queue_size = queue_size
        self._subscribers: list[Subscription] = []
        self._lock = threading.Lock()
        self._ids = itertools.count(1)

    @property
    def subscribers(self) -> int:
        return len(self._subscribers)

    def subscribe(
        self, types: Iterable[str] = EVENT_TYPES, *, port: int | None = None
    ) -> Subscription:
        wanted = frozenset(types)
        unknown = wanted - set(EVENT_TYPES)
        if unknown:
            raise ValueError(f"event types {sorted(unknown)}; allowed: {', '.join(EVENT_TYPES)}")
        sub = Subscription(wanted, port, self.queue_size)
        with self._lock:
            self._subscribers = [*self._subscribers, sub]
        return sub

    def unsubscribe(self, sub: Subscription) -> None:
        with self._lock:
            self._subscribers = [s for s in self._subscribers if s is not sub]

    def publish(self, type_: str, data: dict[str, Any]) -> None:
        """Queue an event for every interested subscriber; never blocks on a slow one."""
        subscribers = self._subscribers  # replaced, never mutated: no lock needed to read
        if not subscribers:
            return
        event = Event(next(self._ids), type_, data)
        for sub in subscribers:
            if sub.wants(event):
                sub._put(event)

    def close(self) -> None:
        """End every subscription (daemon shutdown)."""
