"""Publish/subscribe of daemon events (frames, parameter changes, errors).

Publishers are the frame-sync thread and request handlers; they never wait. An event is
numbered, kept in a short replay buffer and handed to the subscribers in one fan-out:

- subscribers on an asyncio loop (the event streams) are served by one callback per loop
  and batch of events, however many there are, so the frame clock's cost does not grow
  with the number of clients. Each has a bounded queue; a client whose queue overflows
  has fallen behind: it is marked ``overflowed`` (its stream tells it and ends) and
  gets nothing more;
- subscribers in threads (`Subscription.get_blocking`) get each event at once; when their
  queue is full the oldest event is dropped and counted.

Event ids increase by one per event and start at the daemon's start time in microseconds,
so they keep increasing across daemon restarts: a client that reconnects with the last id
it saw (``Last-Event-ID``) gets what it missed from the replay buffer, including the
events of a daemon started since.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import itertools
import json
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

EVENT_TYPES = ("frame", "params", "error", "port")


class TooManyStreamsError(RuntimeError):
    """The hub has as many subscribers as it allows (``max_subscribers``)."""


class HubClosedError(RuntimeError):
    """The hub is closed (the daemon is shutting down)."""


@dataclass(frozen=True)
class Event:
    """One event: a sequence number, its type and a JSON-ready body."""

    id: int
    type: str
    data: dict[str, Any]

    @functools.cached_property
    def sse(self) -> bytes:
        """The event as a server-sent event: encoded once, whatever the number of streams."""
        data = json.dumps(self.data, separators=(",", ":"))
        return f"id: {self.id}\nevent: {self.type}\ndata: {data}\n\n".encode()


def _settle(waiter: asyncio.Future[None]) -> None:
    if not waiter.done():
        waiter.set_result(None)


@dataclass
class Subscription:
    """One subscriber's bounded queue, filled by `EventHub.publish`.

    Wait for events with `get` (on the subscriber's asyncio loop) or `get_blocking`
    (threads). ``missed`` counts events a resumed subscription asked for that the replay
    buffer no longer held; ``dropped`` events lost to a full queue.
    """

    types: frozenset[str]
    port: int | None
    maxlen: int
    loop: asyncio.AbstractEventLoop | None = None
    dropped: int = 0
    missed: int = 0
    overflowed: bool = False
    closed: bool = False
    # Called once on the subscriber's loop when it overflows or the hub closes, so that a
    # stream stuck sending to a client that does not read stops.
    interrupt: Callable[[], None] | None = None
    _queue: deque[Event] = field(default_factory=deque)
    _cond: threading.Condition = field(default_factory=threading.Condition)
    _waiter: asyncio.Future[None] | None = None  # what `get` awaits, on the loop

    def wants(self, event: Event) -> bool:
        if event.type not in self.types:
            return False
        return self.port is None or event.data.get("port", self.port) == self.port

    @property
    def backlog(self) -> int:
        """Events queued and not yet taken."""
        return len(self._queue)

    def _put_blocking(self, event: Event) -> None:
        with self._cond:
            if len(self._queue) >= self.maxlen:
                self._queue.popleft()
                self.dropped += 1
            self._queue.append(event)
            self._cond.notify()

    def _put_async(self, events: Iterable[Event]) -> bool:
        """Queue events (on the loop's thread); False once the subscriber fell behind."""
        for event in events:
            if self.overflowed:
                self.dropped += 1
            elif self.wants(event):
                if len(self._queue) >= self.maxlen:
                    self.overflowed = True
                    self.dropped += 1
                else:
                    self._queue.append(event)
        return not self.overflowed

    def _wake(self) -> None:
        if self.loop is None:
            with self._cond:
                self._cond.notify_all()
        elif self._waiter is not None and not self._waiter.done():
            self._waiter.set_result(None)

    def _interrupt(self) -> None:
        callback, self.interrupt = self.interrupt, None
        if callback is not None:
            callback()

    def pop(self) -> Event | None:
        """The next queued event, or None if none is queued (never waits)."""
        with self._cond:
            return self._queue.popleft() if self._queue else None

    async def get(self, timeout_s: float) -> Event | None:
        """The next event; None after ``timeout_s`` without one, or once closed or overflowed."""
        # A bare future and a timer: asyncio.wait_for would make a task per wait, and a
        # stream waits once per event (thousands a second across the streams under load).
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while True:
            if self.overflowed or self.closed:
                return None
            event = self.pop()
            if event is not None:
                return event
            if loop.time() >= deadline:
                return None
            waiter = self._waiter = loop.create_future()
            timer = loop.call_at(deadline, _settle, waiter)
            try:
                await waiter
            finally:
                timer.cancel()
                self._waiter = None

    def get_blocking(self, timeout_s: float) -> Event | None:
        """The next event, waiting in this thread up to ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while not self._queue:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or self.closed:
                    return None
                self._cond.wait(remaining)
            return self._queue.popleft()


class EventHub:
    """Fan-out of events to subscribers.

    Parameters
    ----------
    queue_size
        Events kept per subscriber: a stream that falls this far behind is dropped; a
        thread subscriber loses its oldest.
    replay
        Events kept for subscribers that resume after a reconnect (``last_id``).
    max_subscribers
        Subscriptions at the same time; one more raises `TooManyStreamsError`.
    first_id
        The first event's id (default: the time now in microseconds since the epoch).
    """

    def __init__(
        self,
        queue_size: int = 256,
        *,
        replay: int = 1024,
        max_subscribers: int = 64,
        first_id: int | None = None,
    ) -> None:
        self.queue_size = queue_size
        self.max_subscribers = max_subscribers
        self.first_id = time.time_ns() // 1000 if first_id is None else first_id
        self.closed = False
        self._ids = itertools.count(self.first_id)
        self._replay: deque[Event] = deque(maxlen=replay)
        self._subscribers: list[Subscription] = []
        self._lock = threading.Lock()
        # Per loop: events not yet handed to that loop's subscribers, and whether a
        # fan-out is scheduled there already.
        self._pending: dict[asyncio.AbstractEventLoop, list[Event]] = {}
        self.fanouts = 0  # fan-out callbacks run (one per loop and batch of events)

    @property
    def subscribers(self) -> int:
        return len(self._subscribers)

    @property
    def last_id(self) -> int:
        """The id of the newest event (first_id - 1 before any)."""
        with self._lock:
            return self._replay[-1].id if self._replay else self.first_id - 1

    def subscribe(
        self,
        types: Iterable[str] = EVENT_TYPES,
        *,
        port: int | None = None,
        loop: asyncio.AbstractEventLoop | None = None,
        last_id: int | None = None,
    ) -> Subscription:
        """A new subscription; with ``loop`` it is served on that asyncio loop.

        ``last_id`` resumes after that event: the replay buffer's later events are queued
        first, and ``missed`` counts those it no longer holds.
        """
        wanted = frozenset(types)
        unknown = wanted - set(EVENT_TYPES)
        if unknown:
            raise ValueError(f"event types {sorted(unknown)}; allowed: {', '.join(EVENT_TYPES)}")
        sub = Subscription(wanted, port, self.queue_size, loop=loop)
        with self._lock:
            if self.closed:
                raise HubClosedError("the daemon is shutting down")
            if len(self._subscribers) >= self.max_subscribers:
                raise TooManyStreamsError(
                    f"{len(self._subscribers)} event streams are open, the limit is "
                    f"{self.max_subscribers}; close one or retry later"
                )
            if last_id is not None:
                self._resume(sub, last_id)
            self._subscribers = [*self._subscribers, sub]
        return sub

    def _resume(self, sub: Subscription, last_id: int) -> None:
        buffered = list(self._replay)
        oldest = buffered[0].id if buffered else self.first_id
        # An id from before this daemon started: everything this daemon published is new.
        after = max(last_id, self.first_id - 1)
        if after + 1 < oldest:
            sub.missed = oldest - after - 1
        later = [e for e in buffered if e.id > after]
        if sub.loop is None:
            for event in later:
                if sub.wants(event):
                    sub._put_blocking(event)
        else:
            sub._put_async(later)

    def unsubscribe(self, sub: Subscription) -> None:
        with self._lock:
            self._subscribers = [s for s in self._subscribers if s is not sub]

    def publish(self, type_: str, data: dict[str, Any]) -> None:
        """Number and keep an event and hand it to the subscribers; never blocks on one."""
        schedule: list[asyncio.AbstractEventLoop] = []
        with self._lock:
            event = Event(next(self._ids), type_, data)
            self._replay.append(event)
            subscribers = self._subscribers
            for sub in subscribers:
                if sub.loop is None:
                    continue
                pending = self._pending.get(sub.loop)
                if pending is None:
                    self._pending[sub.loop] = [event]
                    schedule.append(sub.loop)
                elif pending[-1] is not event:
                    pending.append(event)
        for sub in subscribers:
            if sub.loop is None and sub.wants(event):
                sub._put_blocking(event)
        for loop in schedule:
            # RuntimeError: the loop is gone; its subscribers unsubscribe on their way out.
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(self._fan_out, loop)

    def _fan_out(self, loop: asyncio.AbstractEventLoop) -> None:
        """On ``loop``: hand the pending events to its subscribers (one call per batch)."""
        with self._lock:
            events = self._pending.pop(loop, [])
            subscribers = [s for s in self._subscribers if s.loop is loop]
        self.fanouts += 1
        for sub in subscribers:
            was = sub.backlog
            fine = sub._put_async(events)
            if not fine:
                sub._interrupt()
            if sub.backlog != was or not fine:
                sub._wake()

    def close(self) -> None:
        """End every subscription and refuse new ones (daemon shutdown)."""
        with self._lock:
            self.closed = True
            subscribers = self._subscribers
        for sub in subscribers:
            sub.closed = True
            if sub.loop is None:
                sub._wake()
            else:
                with contextlib.suppress(RuntimeError):
                    sub.loop.call_soon_threadsafe(sub._wake)
                    sub.loop.call_soon_threadsafe(sub._interrupt)
