"""Benchmark of the browser page's live view; prints ONE JSON object.

A 2592 x 1936 Bayer port (the simulated MT9P006, 12 bits) is previewed at 1/4 scale
(648 x 484 JPEG) the way `GET /ports/{port}/preview` makes it: binned demosaic, grey-world
white balance, gamma, JPEG. It runs for --seconds on distinct frames (the frames the
simulator formed, each also shifted by a few pixels, so no two previews share pixels),
while two other clients (in another process) keep the same daemon busy over loopback
HTTP (each: a parameter read, a frame number and a histogram of a full frame, then a
0.25 s pause), as a second page and a monitoring script would.

Peers, measured in the same run on the same frames:

- ``fetch_ms``: the daemon's capture of that frame: ``POST /capture?frame=N`` of the
  already-formed frame over HTTP (16-bit TIFF, the raw frame a client gets).
- ``form_ms``: the simulator forming the frame (what a capture costs on this board).

Target: ``fps`` >= 15 and ``encode_ms`` (JPEG only) < ``fetch_ms``.

Usage: python bench/preview.py [--seconds 10]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import threading
import time
from typing import Any

import httpx
import numpy as np
import uvicorn

from elphel_camd import preview
from elphel_camd.api import create_app
from elphel_camd.service import CameraService
from elphel_sim.board import SimCameraBoard
from elphel_sim.scenarios import build

TOKEN = "bench-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
WIDTH, HEIGHT, FACTOR = 2592, 1936, 4
# Each other client: a parameter read, a frame number and a full-frame histogram, then a
# pause; two of them ask about what a page polling at 1-2 Hz and a monitoring script do.
PAUSE_S = 0.25


def serve(app: Any) -> tuple[uvicorn.Server, str, threading.Thread]:
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning"))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    while not server.started:
        time.sleep(0.02)
    return server, f"http://127.0.0.1:{sock.getsockname()[1]}", thread


# The other clients run in their own process, as they would on other machines: only the
# daemon's own work (serving them) shares this process with the previews.
OTHER_CLIENTS = """
import sys, threading, time, httpx
url, frame, seconds, pause = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
auth = {"Authorization": "Bearer " + sys.argv[5]}  # reads need the token, as by default
done = []
def run():
    with httpx.Client(base_url=url, timeout=60, headers=auth) as c:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            c.get("/api/v1/ports/0/params").raise_for_status()
            c.get("/api/v1/ports/0/frame").raise_for_status()
            c.get("/api/v1/ports/0/histogram", params={"frame": frame}).raise_for_status()
            done.append(3)
            time.sleep(pause)
threads = [threading.Thread(target=run) for _ in range(2)]
for t in threads: t.start()
for t in threads: t.join()
print(sum(done))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    args = parser.parse_args()

    load = os.getloadavg()[0]  # other work on the machine (the figures depend on it)
    board = SimCameraBoard(build("default", seed=1), seed=1)
    camera = CameraService(board)
    camera.set_params(0, {"WOI_WIDTH": WIDTH, "WOI_HEIGHT": HEIGHT, "WOI_TOP": 4})
    board.sim_advance(frames=4)
    form_ms = []
    frames = []
    for _ in range(2):
        board.sim_advance(frames=1)
        n = camera.sequencers[0].this_frame
        t = time.perf_counter()
        got, meta = camera.capture(0, frame=n)
        form_ms.append((time.perf_counter() - t) * 1e3)
        assert got.image.shape == (HEIGHT, WIDTH), got.image.shape
        frames.append((got.frame, got.image, meta["bayer"]))
    bits = camera.sensor(0).bits

    server, url, thread = serve(create_app(camera, token=TOKEN))
    try:
        with httpx.Client(base_url=url, timeout=60, headers=AUTH) as c:
            fetch_ms = []
            for _ in range(3):
                for n, _, _ in frames:
                    t = time.perf_counter()
                    r = c.post("/api/v1/ports/0/capture", params={"frame": n})
                    r.raise_for_status()
                    fetch_ms.append((time.perf_counter() - t) * 1e3)
            # The endpoint itself, once per frame (a new frame is never in its cache).
            r = c.get("/api/v1/ports/0/preview", params={"frame": frames[0][0], "scale": "1/4"})
            r.raise_for_status()
            endpoint_size = [int(r.headers["x-image-width"]), len(r.content)]

        others = subprocess.Popen(
            [
                sys.executable,
                "-c",
                OTHER_CLIENTS,
                url,
                str(frames[0][0]),
                str(args.seconds),
                str(PAUSE_S),
                TOKEN,
            ],
            stdout=subprocess.PIPE,
            text=True,
        )
        variants = [
            (np.roll(image, (2 * dy, 2 * dx), axis=(0, 1)), bayer)
            for _, image, bayer in frames
            for dy, dx in ((0, 0), (1, 3), (3, 1), (5, 7))
        ]
        total_ms, encode_ms, sizes = [], [], []
        started = time.perf_counter()
        k = 0
        while time.perf_counter() - started < args.seconds:
            image, bayer = variants[k % len(variants)]
            k += 1
            t0 = time.perf_counter()
            shown = preview.preview_rgb(image, factor=FACTOR, bayer=bayer, bits=bits)
            t1 = time.perf_counter()
            jpeg = preview.encode_jpeg(shown.rgb)
            t2 = time.perf_counter()
            total_ms.append((t2 - t0) * 1e3)
            encode_ms.append((t2 - t1) * 1e3)
            sizes.append(len(jpeg))
        elapsed = time.perf_counter() - started
        out, _ = others.communicate(timeout=120)
        if others.returncode:
            raise RuntimeError(f"the other clients failed ({others.returncode})")
        served = int(out.strip())
    finally:
        server.should_exit = True
        thread.join()
        camera.close()

    encode = statistics.median(encode_ms)
    fetch = statistics.median(fetch_ms)
    fps = len(total_ms) / elapsed
    print(
        json.dumps(
            {
                "frame": [WIDTH, HEIGHT],
                "preview": [WIDTH // FACTOR, HEIGHT // FACTOR],
                "cpus": os.cpu_count(),
                "load_average_1min": round(load, 1),
                "seconds": round(elapsed, 2),
                "previews": len(total_ms),
                "fps": round(fps, 1),
                "fps_target": 15,
                "fps_vs_target": round(fps / 15, 2),
                "preview_ms_p50": round(statistics.median(total_ms), 2),
                "preview_ms_p95": round(float(np.percentile(total_ms, 95)), 2),
                "encode_ms": round(encode, 2),
                "jpeg_bytes": int(statistics.median(sizes)),
                "fetch_ms": round(fetch, 2),
                "encode_vs_fetch": round(encode / fetch, 3),
                "form_ms": round(statistics.median(form_ms), 1),
                "encode_vs_form": round(encode / statistics.median(form_ms), 4),
                "other_client_requests": served,
                "other_client_rps": round(served / elapsed, 1),
                "endpoint_preview": endpoint_size,
            }
        )
    )


if __name__ == "__main__":
    main()
