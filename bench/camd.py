"""Benchmark of elphel-camd on the simulated board over loopback; prints ONE JSON object.

1. PATCH of one parameter: p50/p99 latency (the change is validated, scheduled, saved
   atomically with fsync, and answered), while the board runs in real time.
2. Fetching an already-formed full 5 MPix 16-bit frame from the ring buffer, against a
   plain FastAPI endpoint that returns the same TIFF bytes from memory, interleaved in the
   same run: the ratio of mean times is the daemon's overhead.
3. Acquisition at the sensor's full frame rate and full resolution for --seconds: every
   frame must reach the ring buffer and the event stream with consecutive numbers and
   evenly spaced timestamps (none dropped), while a client follows the events.

The daemon and the plain endpoints each run as their own process, as deployed. A PATCH to
a plain FastAPI endpoint that validates the same body and does nothing is timed too: the
framework's own floor on this machine.

Usage: python bench/camd.py [--seconds 60] [--patches 500] [--fetches 20]
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx
import uvicorn
from fastapi import FastAPI, Response
from pydantic import BaseModel

from elphel_host.camera.events import SSEParser as _SSEParser
from elphel_sim.demo.rig import stop_child

TOKEN = "bench-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
NODELAY = [(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)]


def wait_for_line(proc: subprocess.Popen[str], log: Path, marker: str) -> str:
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        text = log.read_text()
        if marker in text:
            return text.split(marker, 1)[1].split()[0]
        if proc.poll() is not None:
            raise RuntimeError(f"server exited {proc.returncode}: {text}")
        time.sleep(0.05)
    raise TimeoutError(f"no {marker!r} in {log}")


@contextmanager
def daemon(state: Path, **settings: Any) -> Iterator[str]:
    """`elphel-camd --board sim` as its own process (as deployed); yields its URL."""
    state.mkdir(parents=True, exist_ok=True)
    config = state / "config.json"
    config.write_text(
        json.dumps(
            {
                "state_dir": str(state),
                "board_options": {"seed": 1},
                "access_log": False,
                "log_level": "warning",
                **settings,
            }
        )
    )
    log = state / "daemon.log"
    command = [sys.executable, "-m", "elphel_camd.cli", "--board", "sim", "--config", str(config)]
    with log.open("w") as err:
        proc = subprocess.Popen(
            [*command, "--port", "0"],
            stdout=subprocess.DEVNULL,
            stderr=err,
            env={**os.environ, "ELPHEL_CAMD_TOKEN": TOKEN},
        )
    try:
        yield wait_for_line(proc, log, "listening on ")
    finally:
        stop_child(proc)


@contextmanager
def plain_server(body: Path, state: Path) -> Iterator[str]:
    """This script's --serve-plain mode in its own process; yields its URL."""
    log = state / "plain.log"
    with log.open("w") as out:
        proc = subprocess.Popen(
            [sys.executable, __file__, "--serve-plain", str(body)], stdout=out, stderr=out
        )
    try:
        yield wait_for_line(proc, log, "plain endpoint on ")
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=20)


class Change(BaseModel):
    """The body of the plain PATCH endpoint."""

    GAINR: int


def serve_plain(path: Path) -> int:
    """Serve GET /frame returning the bytes of ``path`` from memory (the reference)."""
    body = path.read_bytes()
    app = FastAPI()

    @app.get("/frame")
    def frame_bytes() -> Response:
        return Response(content=body, media_type="image/tiff")

    @app.patch("/ports/{port}/params")
    def set_gain(port: int, change: Change) -> dict[str, Any]:
        """The floor for a PATCH: a validated body answered, nothing done."""
        return {"frame": 0, "params": change.model_dump()}

    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.bind(("127.0.0.1", 0))
    sock.listen(128)
    print(f"plain endpoint on http://127.0.0.1:{sock.getsockname()[1]}", flush=True)
    config = uvicorn.Config(app, log_level="warning", access_log=False, lifespan="off")
    uvicorn.Server(config).run(sockets=[sock])
    sock.close()
    return 0


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q / 100 * (len(ordered) - 1)))]


def bench_plain_patch(url: str, count: int) -> dict[str, Any]:
    """The same PATCH against a FastAPI endpoint that does nothing: the framework's floor."""
    transport = httpx.HTTPTransport(socket_options=NODELAY)
    times = []
    with httpx.Client(base_url=url, timeout=30, transport=transport) as http:
        for i in range(count + 20):
            t0 = time.perf_counter()
            http.patch("/ports/0/params", json={"GAINR": 0x10000 + i}).raise_for_status()
            if i >= 20:
                times.append((time.perf_counter() - t0) * 1e3)
    return {
        "count": count,
        "p50_ms": round(percentile(times, 50), 3),
        "p99_ms": round(percentile(times, 99), 3),
    }


def bench_patch(url: str, count: int) -> dict[str, Any]:
    """PATCH latency, and GET /frame latency on the same connection as the floor."""
    # As the host client does: no Nagle delay between a request's headers and its body.
    transport = httpx.HTTPTransport(socket_options=NODELAY)
    patch, floor = [], []
    with httpx.Client(
        base_url=url + "/api/v1", headers=AUTH, timeout=30, transport=transport
    ) as http:
        for i in range(count + 20):
            t0 = time.perf_counter()
            r = http.patch("/ports/0/params", json={"GAINR": 0x10000 + (i % 64) * 0x400})
            t1 = time.perf_counter()
            r.raise_for_status()
            http.get("/ports/0/frame").raise_for_status()
            t2 = time.perf_counter()
            if i >= 20:  # warm-up
                patch.append((t1 - t0) * 1e3)
                floor.append((t2 - t1) * 1e3)
    return {
        "count": count,
        "p50_ms": round(percentile(patch, 50), 3),
        "p99_ms": round(percentile(patch, 99), 3),
        "max_ms": round(max(patch), 3),
        "get_frame_p50_ms": round(percentile(floor, 50), 3),
        "get_frame_p99_ms": round(percentile(floor, 99), 3),
    }


def bench_ring_fetch(url: str, state: Path, fetches: int) -> dict[str, Any]:
    with httpx.Client(base_url=url + "/api/v1", headers=AUTH, timeout=120) as http:
        # Stop the trigger: no new frame pushes the fetched one out of the ring meanwhile.
        http.patch("/ports/0/params", json={"TRIG": 4, "TRIG_PERIOD": 0}).raise_for_status()
        last = -1
        while (now := http.get("/ports/0/frame").json()["frame"]) != last:
            last = now
            time.sleep(1.0)
        first = http.post(f"/ports/0/capture?frame={last}")  # forms the full frame once
        first.raise_for_status()
        body = first.content
        (state / "frame.tif").write_bytes(body)
        ours: list[float] = []
        theirs: list[float] = []
        with plain_server(state / "frame.tif", state) as plain_url:
            for i in range(fetches + 2):
                # Alternate which endpoint goes first, so neither gains from the order.
                order = [("ring", ours), ("plain", theirs)]
                for which, times in order if i % 2 else order[::-1]:
                    t0 = time.perf_counter()
                    if which == "ring":
                        r = http.post(f"/ports/0/capture?frame={last}")
                    else:
                        r = http.get(plain_url + "/frame")
                    times.append(time.perf_counter() - t0)
                    if r.content != body:
                        raise AssertionError(f"the {which} endpoint returned other bytes")
        http.patch("/ports/0/params", json={"TRIG": 0}).raise_for_status()
    ours, theirs = ours[2:], theirs[2:]  # warm-up
    mb = len(body) / 1e6
    mean_ours, mean_plain = statistics.fmean(ours), statistics.fmean(theirs)
    return {
        "frame": last,
        "frame_bytes": len(body),
        "fetches": fetches,
        "ring_mb_per_s": round(mb / mean_ours, 1),
        "plain_mb_per_s": round(mb / mean_plain, 1),
        "ring_ms": round(mean_ours * 1e3, 2),
        "plain_ms": round(mean_plain * 1e3, 2),
        "ratio": round(mean_ours / mean_plain, 3),
    }


def bench_acquisition(url: str, seconds: float) -> dict[str, Any]:
    """Follow frame events for ``seconds``; every frame must be there, evenly spaced."""
    frames: list[tuple[int, int]] = []
    dropped = 0
    parser = _SSEParser()
    with httpx.Client(base_url=url + "/api/v1", headers=AUTH, timeout=30) as http:
        params = http.get("/ports/0/params").json()
        period_s = 1000.0 / params["FP1000S"]
        deadline = time.monotonic() + seconds
        stream_timeout = httpx.Timeout(30, read=None)
        with http.stream("GET", "/events?types=frame&port=0", timeout=stream_timeout) as r:
            for line in r.iter_lines():
                event = parser.feed(line)
                if event is not None and event.type == "dropped":
                    dropped = int(event.data["dropped"])
                elif event is not None:
                    frames.append((int(event.data["frame"]), int(event.data["timestamp_ns"])))
                if time.monotonic() > deadline:
                    break
        # The newest frames are in the ring buffer: the last one is fetched by its number.
        newest = frames[-1][0]
        fetched = http.post(f"/ports/0/capture?frame={newest}")
    numbers = [f for f, _ in frames]
    gaps = sum(1 for a, b in itertools.pairwise(numbers) if b != a + 1)
    spacing = [(b - a) / 1e9 for (_, a), (_, b) in itertools.pairwise(frames)]
    irregular = sum(1 for s in spacing if abs(s - period_s) > 0.01 * period_s)
    return {
        "seconds": seconds,
        "resolution": [params["WOI_WIDTH"], params["WOI_HEIGHT"]],
        "frame_rate_hz": round(1 / period_s, 3),
        "frames": len(numbers),
        "expected_frames": round(seconds / period_s),
        "gaps": gaps,
        "irregular_intervals": irregular,
        "events_dropped": dropped,
        "dropped_frames": gaps + dropped,
        "newest_fetched_from_ring": fetched.status_code == 200
        and int(fetched.headers["X-Frame-Number"]) == newest,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="acquisition run (default 60)")
    ap.add_argument("--patches", type=int, default=500, help="PATCH requests timed")
    ap.add_argument("--fetches", type=int, default=20, help="full frames fetched per endpoint")
    ap.add_argument("--serve-plain", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.serve_plain:
        return serve_plain(args.serve_plain)

    with tempfile.TemporaryDirectory() as tmp:
        state = Path(tmp)
        with daemon(state / "sync", params_fsync_each=True) as url:
            patch_fsync_each = bench_patch(url, max(args.patches // 5, 50))
        (state / "frame.tif").write_bytes(b"")
        with plain_server(state / "frame.tif", state) as plain_url:
            plain_patch = bench_plain_patch(plain_url, args.patches)
        with daemon(state / "default") as url:
            patch = bench_patch(url, args.patches)
            acquisition = bench_acquisition(url, args.seconds)
            ring = bench_ring_fetch(url, state, args.fetches)
    result = {
        "patch": patch,
        "patch_fsync_before_answer": patch_fsync_each,
        "plain_fastapi_patch": plain_patch,
        "ring_fetch": ring,
        "acquisition": acquisition,
        "targets": {
            "patch_p99_le_5ms": patch["p99_ms"] <= 5.0,
            "ring_fetch_within_1_5x_plain": ring["ratio"] <= 1.5,
            "zero_dropped_frames": acquisition["dropped_frames"] == 0 and acquisition["frames"] > 0,
        },
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
