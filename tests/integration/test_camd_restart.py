"""Faults of a served daemon: SIGTERM with event streams connected, and a restart with a
connected host client (no lost event, no PATCH applied twice)."""

from __future__ import annotations

import contextlib
import itertools
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import pytest

from elphel_host.camera.client import CameraClient
from elphel_host.camera.events import CameraEvent
from elphel_host.errors import CameraClientError

from .rig import start_rig, stop_rig

TOKEN = "restart-token"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_camd(port: int, state: Path) -> subprocess.Popen[str]:
    cmd = [sys.executable, "-m", "elphel_camd.cli", "--board", "sim", "--port", str(port)]
    cmd += ["--token", TOKEN, "--state-dir", str(state)]
    log = state.parent / "camd.log"
    with log.open("a") as err:
        proc = subprocess.Popen(
            cmd, stdout=subprocess.DEVNULL, stderr=err, text=True, env=dict(os.environ)
        )
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            pytest.fail(f"elphel-camd exited: {log.read_text()}")
        try:
            if httpx.get(f"http://127.0.0.1:{port}/api/v1/health", timeout=1).status_code:
                return proc
        except httpx.HTTPError:
            time.sleep(0.2)
    proc.kill()
    pytest.fail("elphel-camd did not answer in 60 s")


def stop(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.kill()
        proc.wait()


def open_streams(url: str, n: int, token: str | None) -> tuple[list[threading.Thread], list[float]]:
    """``n`` event streams read in threads; the time each one ended."""
    ended: list[float] = []
    headers = {"Authorization": f"Bearer {token}"} if token else {}

    def follow() -> None:
        try:
            with httpx.stream(
                "GET",
                url + "/api/v1/events",
                headers=headers,
                timeout=httpx.Timeout(10, read=None),
            ) as r:
                assert r.status_code == 200, r.status_code  # else it ends at once
                for _ in r.iter_lines():
                    pass
        except httpx.HTTPError:
            pass
        ended.append(time.monotonic())

    threads = [threading.Thread(target=follow, daemon=True) for _ in range(n)]
    for t in threads:
        t.start()
    return threads, ended


def test_sigterm_with_event_streams_connected_stops_at_once(tmp_path):
    port = free_port()
    proc = start_camd(port, tmp_path / "state")
    try:
        threads, ended = open_streams(f"http://127.0.0.1:{port}", 3, TOKEN)
        time.sleep(1.0)
        assert not ended  # the streams are open (an answer without a stream ends at once)
        start = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=10)
        exited = time.monotonic() - start
        for t in threads:
            t.join(5)
        assert len(ended) == 3
        assert max(ended) - start < 1.0  # the streams end within a second
        assert exited < 3.0
    finally:
        stop(proc)


def test_sim_up_sigterm_with_event_streams_connected_stops_at_once():
    proc, rig = start_rig()
    try:
        threads, ended = open_streams(rig["camera_url"], 3, rig["token"])
        time.sleep(1.0)
        assert not ended  # the streams are open (an answer without a stream ends at once)
        start = time.monotonic()
        stop_rig(proc, timeout=10)
        exited = time.monotonic() - start
        for t in threads:
            t.join(5)
        assert len(ended) == 3 and max(ended) - start < 1.0
        assert exited < 5.0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_restart_with_a_connected_client_loses_no_event_and_repeats_no_patch(tmp_path):
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    state = tmp_path / "state"
    proc = start_camd(port, state)
    got: list[CameraEvent] = []
    client = CameraClient(url, TOKEN, retry_s=60)
    listener = CameraClient(url, TOKEN, retry_s=60)

    def listen() -> None:
        with contextlib.suppress(CameraClientError, RuntimeError):  # the listener closed
            for event in listener.events(("params",)):
                got.append(event)

    def params_seen() -> list[int]:
        return [e.data["changes"]["EXPOS"] for e in got if e.type == "params"]

    def wait_for(n: int) -> None:
        deadline = time.monotonic() + 30
        while len(params_seen()) < n and time.monotonic() < deadline:
            time.sleep(0.05)

    thread = threading.Thread(target=listen, daemon=True)
    thread.start()
    try:
        time.sleep(1.0)  # the stream is open
        values = [1000, 1100, 1200]
        for v in values:
            client.set_params({"EXPOS": v})
        wait_for(3)
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=10)
        # The daemon is down: this PATCH and this read wait (retrying) until it is back.
        answers: list[object] = []
        writer = threading.Thread(
            target=lambda: answers.append(client.set_params({"EXPOS": 1300})), daemon=True
        )
        reader = threading.Thread(target=lambda: answers.append(client.info()), daemon=True)
        writer.start()
        reader.start()
        time.sleep(1.5)
        assert not answers  # still retrying
        proc = start_camd(port, state)
        writer.join(30)
        reader.join(30)
        assert len(answers) == 2
        applied = [client.set_params({"EXPOS": v}) for v in (1400, 1500)]
        wait_for(6)
        # Every change seen once, in order: none lost across the restart, none repeated.
        assert params_seen() == [1000, 1100, 1200, 1300, 1400, 1500]
        ids = [e.id for e in got if e.type == "params"]
        assert all(a is not None and b is not None and a < b for a, b in itertools.pairwise(ids))
        assert not [e for e in got if e.type == "dropped"]
        in_effect = client.params(frame=applied[-1].frame)["EXPOS"]
        assert abs(in_effect - 1500) < 20  # the last write is what holds (row-time rounding)
    finally:
        listener.close()
        client.close()
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=10)
        stop(proc)
