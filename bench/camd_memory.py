"""Memory of elphel-camd after bursts: is it given back? Prints ONE JSON object.

The daemon runs as its own process (`elphel-camd --board sim`, the default scenario at
full resolution, real time), as bench/load.py starts it. Its resident memory (RSS) is
read when it idles after one warm-up capture (the peer), then under load:
``--abandoned`` full-resolution captures of ``--count`` frames each, every one dropped by
its client after ``--read-mb`` MB (two at a time), and ``--complete`` bursts of 16 frames
read to the end; then each ``--sample-s`` seconds for ``--after-s`` seconds after the
load ended. Reported: the RSS at idle, its peak, at the end, the end/idle ratio (the
daemon's promise: at most 1.2 a minute after the load), and the same of its
image-forming children (the simulated sensor and FPGA) apart.

Usage: python bench/camd_memory.py [--abandoned 6] [--count 200] [--after-s 60]
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path
from urllib.parse import urlsplit

from load import TOKEN, daemon, rss_mb  # bench/load.py

FULL = {"WOI_WIDTH": 2592, "WOI_HEIGHT": 1944, "WOI_LEFT": 0, "WOI_TOP": 0}


def request(url: str, method: str, path: str, body: bytes = b"") -> socket.socket:
    """A raw HTTP/1.1 request sent on a new connection (left open for the answer)."""
    parts = urlsplit(url)
    sock = socket.create_connection((parts.hostname, parts.port), timeout=120)
    head = (
        f"{method} {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {TOKEN}\r\n"
        f"Content-Type: application/json\r\nContent-Length: {len(body)}\r\n"
        "Connection: close\r\n\r\n"
    )
    sock.sendall(head.encode() + body)
    return sock


def read(sock: socket.socket, limit_bytes: int | None = None) -> int:
    """Read the answer until it ends (or ``limit_bytes`` came); the bytes read."""
    got = 0
    while limit_bytes is None or got < limit_bytes:
        chunk = sock.recv(1 << 20)
        if not chunk:
            break
        got += len(chunk)
    sock.close()
    return got


def abandoned(url: str, count: int, read_mb: float) -> int:
    sock = request(url, "POST", f"/api/v1/ports/0/capture?count={count}")
    return read(sock, int(read_mb * 2**20))


def children_rss_mb(pid: int) -> float:
    """The RSS of a process's children (the image-forming processes)."""
    total = 0.0
    for task in Path(f"/proc/{pid}/task").iterdir():
        for child in (task / "children").read_text().split():
            total += rss_mb(int(child))
    return round(total, 1)


def load(url: str, args: argparse.Namespace, peak: list[float], pid: int) -> None:
    """The abandoned and complete bursts, two at a time; ``peak`` follows the RSS."""
    jobs = [lambda: abandoned(url, args.count, args.read_mb)] * args.abandoned
    jobs += [lambda: read(request(url, "POST", "/api/v1/ports/0/capture?count=16"))] * (
        args.complete
    )
    for k in range(0, len(jobs), 2):
        threads = [threading.Thread(target=job) for job in jobs[k : k + 2]]
        for t in threads:
            t.start()
        while any(t.is_alive() for t in threads):
            peak.append(rss_mb(pid))
            time.sleep(0.2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--abandoned", type=int, default=6)
    parser.add_argument("--complete", type=int, default=2)
    parser.add_argument("--count", type=int, default=200)
    parser.add_argument("--read-mb", type=float, default=60.0)
    parser.add_argument("--after-s", type=float, default=60.0)
    parser.add_argument("--sample-s", type=float, default=5.0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp, daemon(Path(tmp)) as (url, pid):
        read(request(url, "PATCH", "/api/v1/ports/0/params", json.dumps(FULL).encode()))
        read(request(url, "POST", "/api/v1/ports/0/capture"))
        time.sleep(10)
        idle = rss_mb(pid)
        children_idle = children_rss_mb(pid)
        peak: list[float] = [idle]
        start = time.monotonic()
        load(url, args, peak, pid)
        load_s = time.monotonic() - start
        after = []
        for _ in range(int(args.after_s / args.sample_s)):
            time.sleep(args.sample_s)
            after.append(rss_mb(pid))
        children_end = children_rss_mb(pid)
        result = {
            "bench": "camd_memory",
            "abandoned": args.abandoned,
            "count": args.count,
            "complete": args.complete,
            "load_s": round(load_s, 1),
            "rss_idle_mb": idle,
            "rss_peak_mb": max(peak),
            "rss_after_mb": after,
            "rss_end_mb": after[-1],
            "end_over_idle": round(after[-1] / idle, 3),
            "children_rss_idle_mb": children_idle,
            "children_rss_end_mb": children_end,
            "children_end_over_idle": round(children_end / children_idle, 3),
        }
    json.dump(result, sys.stdout)
    print()


if __name__ == "__main__":
    main()
