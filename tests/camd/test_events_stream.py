"""The event stream under load and faults: ids and replay, one fan-out per batch, bounded
queues (a stalled client is dropped), a bounded number of streams, shutdown within a
second, request timeouts and a capture pool apart from the request pool."""

import asyncio
import contextlib
import socket
import threading
import time

import httpx
import pytest

from elphel_camd.events import EventHub, TooManyStreamsError
from elphel_camd.service import CameraService
from elphel_host.camera.events import SSEParser
from elphel_sim.board import SimCameraBoard
from elphel_sim.scenarios import build

from .served import AUTH, serve

QUEUE = 16  # events a subscription may have queued before it is dropped
SMALL = {"WOI_WIDTH": 64, "WOI_HEIGHT": 48, "WOI_LEFT": 1200, "WOI_TOP": 900}


@pytest.fixture
def service():
    board = SimCameraBoard(build("default", seed=4), seed=4)
    cam = CameraService(board, events=EventHub(QUEUE, replay=64, max_subscribers=4))
    cam.set_params(0, SMALL)
    board.sim_advance(frames=2)
    yield cam
    cam.close()


def read_events(url: str, out: list, *, params=None, headers=None, limit=10**9) -> None:
    """Collect (type, id, data) of a stream until it ends or ``limit`` events came."""
    parser = SSEParser()
    with httpx.stream(
        "GET",
        url + "/api/v1/events",
        params=params,
        headers=headers,
        timeout=httpx.Timeout(10, read=None),
    ) as r:
        out.append(("status", r.status_code, None))
        for line in r.iter_lines():
            event = parser.feed(line)
            if event is not None:
                out.append((event.type, event.id, event.data))
                if len(out) > limit:
                    return


def wait_until(predicate, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return predicate()


# -- the hub alone --------------------------------------------------------------------------


def test_ids_increase_and_a_resumed_subscription_gets_what_it_missed():
    hub = EventHub(16, replay=16, first_id=1000)
    for k in range(10):
        hub.publish("params", {"port": 0, "k": k})
    assert hub.last_id == 1009
    sub = hub.subscribe(["params"], last_id=1004)
    got = [sub.get_blocking(0.01) for _ in range(5)]
    assert [e.id for e in got] == [1005, 1006, 1007, 1008, 1009] and sub.missed == 0
    assert sub.get_blocking(0.01) is None
    # An id from before this hub started (a daemon restart): everything it has is new.
    again = hub.subscribe(["params"], last_id=12)
    assert again.get_blocking(0.01).id == 1000 and again.missed == 0
    for k in range(20):  # the replay buffer (16) forgets the oldest
        hub.publish("params", {"port": 0, "k": k})
    late = hub.subscribe(["params"], last_id=1009)
    assert late.missed == 4 and late.get_blocking(0.01).id == 1014


def test_one_fan_out_per_batch_not_per_subscriber():
    hub = EventHub(10_000, max_subscribers=100)
    loop = asyncio.new_event_loop()
    try:
        subs = [hub.subscribe(["frame"], loop=loop) for _ in range(50)]
        calls = 0
        real = loop.call_soon_threadsafe

        def counting(*args, **kwargs):
            nonlocal calls
            calls += 1
            return real(*args, **kwargs)

        loop.call_soon_threadsafe = counting  # type: ignore[method-assign]
        for k in range(200):
            hub.publish("frame", {"port": 0, "frame": k})
        loop.run_until_complete(asyncio.sleep(0.05))
        assert calls <= 200  # at most one per event for all 50 subscribers (was 50 per event)
        assert all(s.backlog == 200 for s in subs)
        assert hub.fanouts == calls
    finally:
        loop.close()


def test_async_get_waits_for_an_event_or_the_timeout_and_leaves_nothing_behind():
    hub = EventHub(16)

    async def scenario() -> None:
        loop = asyncio.get_running_loop()
        sub = hub.subscribe(["params"], loop=loop)
        # Nothing published: None after the timeout, not before.
        start = loop.time()
        assert await sub.get(0.2) is None
        assert 0.19 <= loop.time() - start < 1.0
        # Published from another thread while waiting: returned at once, in order.
        timer = threading.Timer(0.05, lambda: [hub.publish("params", {"k": k}) for k in range(3)])
        timer.start()
        start = loop.time()
        first = await sub.get(5.0)
        assert first is not None and first.data == {"k": 0} and loop.time() - start < 1.0
        assert [(await sub.get(5.0)).data["k"] for _ in range(2)] == [1, 2]
        # An event of another type wakes nothing: the wait still ends at its timeout.
        loop.call_later(0.05, hub.publish, "frame", {"port": 0})
        assert await sub.get(0.2) is None
        # A cancelled wait leaves no waiter and no timer; the next get works.
        task = asyncio.create_task(sub.get(30.0))
        await asyncio.sleep(0.05)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        assert sub._waiter is None
        hub.publish("params", {"k": 9})
        assert (await sub.get(5.0)).data == {"k": 9}
        # Closing the hub ends a wait at once.
        loop.call_later(0.05, hub.close)
        start = loop.time()
        assert await sub.get(30.0) is None and loop.time() - start < 1.0

    asyncio.run(scenario())


def test_subscriber_limit_and_overflow():
    hub = EventHub(4, max_subscribers=2)
    loop = asyncio.new_event_loop()
    try:
        slow = hub.subscribe(["frame"], loop=loop)
        hub.subscribe(["frame"], loop=loop)
        with pytest.raises(TooManyStreamsError, match="limit is 2"):
            hub.subscribe()
        for k in range(6):
            hub.publish("frame", {"port": 0, "frame": k})
        loop.run_until_complete(asyncio.sleep(0.01))
        assert slow.overflowed and slow.backlog == 4 and slow.dropped == 2
    finally:
        loop.close()


# -- served ---------------------------------------------------------------------------------


def test_stream_ids_and_last_event_id_resume(service):
    hub = service.events
    with serve(service) as srv:
        start = hub.last_id
        for k in range(5):
            hub.publish("params", {"port": 0, "frame": k})
        first: list = []
        read_events(
            srv.url,
            first,
            params={"types": "params", "count": 5},
            headers={"Last-Event-ID": str(start)},
        )
        assert first[0] == ("status", 200, None)
        ids = [i for _, i, _ in first[1:]]
        assert ids == list(range(start + 1, start + 6))
        assert [d["frame"] for _, _, d in first[1:]] == list(range(5))
        for k in range(5, 8):
            hub.publish("params", {"port": 0, "frame": k})
        resumed: list = []
        read_events(
            srv.url,
            resumed,
            params={"types": "params", "count": 3},
            headers={"Last-Event-ID": str(ids[-1])},
        )
        assert [i for _, i, _ in resumed[1:]] == [ids[-1] + 1, ids[-1] + 2, ids[-1] + 3]
        assert [d["frame"] for _, _, d in resumed[1:]] == [5, 6, 7]
        bad = httpx.get(srv.url + "/api/v1/events", headers={"Last-Event-ID": "x"})
        assert bad.status_code == 422 and "Last-Event-ID" in bad.json()["detail"]


def test_stalled_listener_is_dropped_and_the_others_get_everything(service):
    with serve(service) as srv, socket.socket(socket.AF_INET, socket.SOCK_STREAM) as stalled:
        stalled.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        stalled.connect(("127.0.0.1", int(srv.url.rsplit(":", 1)[1])))
        stalled.sendall(b"GET /api/v1/events?types=params HTTP/1.1\r\nHost: camera\r\n\r\n")
        assert wait_until(lambda: service.events.subscribers == 1)
        good: list = []
        reader = threading.Thread(
            target=read_events,
            args=(srv.url, good),
            kwargs={"params": {"types": "params"}, "limit": 400},
            daemon=True,
        )
        reader.start()
        assert wait_until(lambda: service.events.subscribers == 2)
        pad = "x" * 8000
        for k in range(400):  # ~3 MB: more than the stalled socket's buffers hold
            # the good reader keeps up however busy the machine is: at most QUEUE // 2
            # events are published and not yet read, so its queue of QUEUE never fills
            # (what is queued is at most what is published and unread); the stalled one
            # never reads
            assert wait_until(lambda k=k: len(good) - 1 >= k - QUEUE // 2)
            service.events.publish("params", {"port": 0, "frame": k, "pad": pad})
            time.sleep(0.001)
        assert wait_until(lambda: service.events.subscribers == 1, 5)  # the stalled one left
        reader.join(10)
        frames = [d["frame"] for t, _, d in good[1:] if t == "params"]
        assert frames == list(range(400))
        assert not any(t == "dropped" for t, _, _ in good)
        # The stalled connection was cut: reading it ends (EOF or reset), never hangs.
        stalled.settimeout(5)
        received = b""
        with contextlib.suppress(ConnectionResetError):
            while chunk := stalled.recv(65536):
                received += chunk
        assert received.startswith(b"HTTP/1.1 200")


def test_stream_limit_is_a_503_naming_it(service):
    with serve(service) as srv:
        streams = []
        for _ in range(4):
            s = socket.create_connection(("127.0.0.1", int(srv.url.rsplit(":", 1)[1])))
            s.sendall(b"GET /api/v1/events HTTP/1.1\r\nHost: camera\r\n\r\n")
            streams.append(s)
        assert wait_until(lambda: service.events.subscribers == 4)
        r = httpx.get(srv.url + "/api/v1/events", timeout=5)
        assert r.status_code == 503
        assert "event stream limit" in r.json()["detail"] and "limit is 4" in r.json()["detail"]
        assert r.headers["retry-after"]
        for s in streams:
            s.close()


def test_shutdown_ends_event_streams_within_a_second(service):
    service.board.start_clock()
    with serve(service) as srv:
        outs = [[] for _ in range(3)]
        readers = [
            threading.Thread(target=read_events, args=(srv.url, out), daemon=True) for out in outs
        ]
        for r in readers:
            r.start()
        # Every stream is live (its status and at least one event arrived) before the stop;
        # subscribed alone is not enough: under a loaded CI the first frame can come later.
        start = time.monotonic()
        live = wait_until(lambda: service.events.subscribers == 3)
        waited = time.monotonic() - start
        assert live, (f"{service.events.subscribers} of 3 streams after {waited:.1f} s", outs)
        assert wait_until(lambda: all(len(out) > 1 for out in outs))
        took = srv.stop()
        assert took < 1.5 and not srv.thread.is_alive()
        for r in readers:
            r.join(2)
            assert not r.is_alive()


def test_half_open_and_slow_requests_are_dropped(service):
    with serve(service, request_timeout_s=1.0, idle_timeout_s=1.0) as srv:
        port = int(srv.url.rsplit(":", 1)[1])
        silent = socket.create_connection(("127.0.0.1", port))
        slow = socket.create_connection(("127.0.0.1", port))
        slow.sendall(b"GET /api/v1/info HTTP/1.1\r\nHost: camera\r\n")  # never finished
        start = time.monotonic()
        for s in (silent, slow):
            s.settimeout(5)
            with contextlib.suppress(ConnectionResetError):
                assert s.recv(1024) == b""
            s.close()
        assert time.monotonic() - start < 3
        assert httpx.get(srv.url + "/api/v1/info", timeout=5).status_code == 200


def test_waiting_captures_do_not_slow_other_requests(service):
    service.board.start_clock()
    service.set_params(0, {"TRIG": 4, "TRIG_PERIOD": 0})  # trigger stopped: captures wait
    with serve(service) as srv:
        results: list[int] = []

        def capture() -> None:
            try:
                r = httpx.post(srv.url + "/api/v1/ports/0/capture", headers=AUTH, timeout=30)
                results.append(r.status_code)
            except httpx.HTTPError:
                results.append(-1)

        threads = [threading.Thread(target=capture, daemon=True) for _ in range(45)]
        for t in threads:
            t.start()
        assert wait_until(lambda: service.capture_pool.waiting == 45, 30)
        # one kept-alive client, so that the time is the daemon's answers, not a new
        # httpx client per request (about 30 ms each on its own, 6x that on a busy CI)
        with httpx.Client(base_url=srv.url, timeout=5) as client:
            start = time.monotonic()
            for _ in range(5):
                assert client.get("/api/v1/info").status_code == 200
                patch = client.patch("/api/v1/ports/0/params", json={"EXPOS": 3000}, headers=AUTH)
                assert patch.status_code == 200
            assert (time.monotonic() - start) / 5 < 0.5
        # Beyond the pool's bound a capture is refused at once, naming the limit.
        service.capture_pool.max_waiting = 45
        r = httpx.post(srv.url + "/api/v1/ports/0/capture", headers=AUTH, timeout=5)
        assert r.status_code == 503 and "capture wait pool full" in r.json()["detail"]
        service.board.close()  # the waiting captures fail at once
        for t in threads:
            t.join(10)
        assert len(results) == 45 and all(code == 501 for code in results)


def test_an_idle_stream_ends_after_stream_idle_s_keepalives_not_counting(service):
    with serve(service, keepalive_s=0.2, stream_idle_s=1.5) as srv:
        lines: list[str] = []
        start = time.monotonic()
        with httpx.stream(
            "GET",
            srv.url + "/api/v1/events",
            params={"types": "error"},
            timeout=httpx.Timeout(10, read=5),
        ) as r:
            assert r.status_code == 200
            done = threading.Event()

            def publish() -> None:  # errors for 2 s: each one restarts the idle time
                for k in range(8):
                    service.events.publish("error", {"port": 0, "frame": k, "detail": "x"})
                    time.sleep(0.25)
                done.set()

            threading.Thread(target=publish, daemon=True).start()
            lines.extend(r.iter_lines())  # ends when the daemon closes the stream
        took = time.monotonic() - start
        assert done.is_set()
        assert sum(line.startswith("event: error") for line in lines) == 8
        assert sum(line == ": keepalive" for line in lines) >= 4  # they did not keep it open
        assert ": no event for 1.5 s: closed" in lines
        # 2 s of errors, then 1.5 s idle: closed then, not before and not much later.
        assert 3.0 <= took < 5.5, took
        assert wait_until(lambda: service.events.subscribers == 0)
