"""A daemon app served by the real server (elphel_camd.serving) in a thread, for tests.

Event streams, timeouts, connection aborts and shutdown need a real socket; FastAPI's test
client has none.
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from elphel_camd.api import create_app
from elphel_camd.service import CameraService
from elphel_camd.serving import GracefulServer, server_config

TOKEN = "test-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@dataclass
class Served:
    url: str
    server: GracefulServer
    thread: threading.Thread

    def stop(self, timeout_s: float = 10.0) -> float:
        """Ask the server to stop (as SIGTERM does); the seconds it took."""
        start = time.monotonic()
        self.server.should_exit = True
        self.thread.join(timeout_s)
        return time.monotonic() - start


@contextlib.contextmanager
def serve(service: CameraService, *, public_reads: bool = True, **config: Any) -> Iterator[Served]:
    """Serve ``service``; reads are open by default (these tests are about streams and
    connections; tests/camd/test_security.py is about the token)."""
    app = create_app(
        service,
        token=TOKEN,
        public_reads=public_reads,
        keepalive_s=config.pop("keepalive_s", 15.0),
        stream_idle_s=config.pop("stream_idle_s", 300.0),
    )
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind(("127.0.0.1", 0))
    sock.listen(128)
    port = sock.getsockname()[1]
    server = GracefulServer(
        server_config(app, log_level="warning", access_log=False, **config),
        on_shutdown=[service.events.close],
        handle_signals=False,
    )
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    start = time.monotonic()
    while not server.started and time.monotonic() < start + 10:
        time.sleep(0.01)
    served = Served(f"http://127.0.0.1:{port}", server, thread)
    if not server.started:  # say so here rather than as a later test's timeout
        served.stop()
        sock.close()
        raise RuntimeError(f"the server did not start within {time.monotonic() - start:.1f} s")
    try:
        yield served
    finally:
        if thread.is_alive():
            served.stop()
        sock.close()
