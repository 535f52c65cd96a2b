"""V4L2 image-path benchmark on a synthetic node on the host (guest timings mean nothing).

In the same run:
- placing a 3280x2464 CSI-2 RAW10 frame (the IMX219's full frame, 10.1 MB) in the frame
  ring, against a plain NumPy copy of the same bytes into an array made before (the peer),
  best of N, alternating;
- unpacking that frame to 16-bit pixels (done when a frame is fetched), against the same
  copy;
- streaming a 5 MPix RAW10 node (2592x1944) at 15 fps through the v4l2 board for a few
  seconds on one core: frames, dropped frames, CPU used per second of streaming.
Prints exactly one JSON object.

    .venv/bin/python bench/v4l2.py [--repeat 15 --stream-s 8]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from typing import Any

import numpy as np

from elphel_camd.boards.v4l2 import V4L2Board, V4L2Port
from elphel_camd.v4l2.formats import raw_format
from elphel_camd.v4l2.ring import FrameRing
from elphel_camd.v4l2.source import StreamFormat
from elphel_camd.v4l2.synthetic import SyntheticSource, pack
from elphel_camd.v4l2.unpack import unpack

FULL = (2464, 3280)  # IMX219 full frame, rows x columns
FIVE_MPIX = (1944, 2592)


def image(shape: tuple[int, int], seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 1024, shape, dtype=np.uint16)


def best_ms(fn: Any, repeat: int) -> float:
    fn()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times) * 1e3


def placement(repeat: int) -> dict[str, Any]:
    """Ring placement and unpacking of one full RAW10 frame, each against a copy."""
    fmt = raw_format("pRAA")
    height, width = FULL
    stream = StreamFormat(fmt, width, height, fmt.line_bytes(width))
    data = pack(image(FULL), fmt, stride=stream.stride).reshape(-1)
    ring = FrameRing(4)
    peer = np.empty_like(data)
    out = np.empty(FULL, np.uint16)
    frame = iter(range(1, 1 << 30))
    times = {"copy": [], "place": [], "unpack": []}
    for _ in range(repeat):  # alternate, so all three see the same machine load
        times["copy"].append(best_ms(lambda: np.copyto(peer, data), 1))
        times["place"].append(
            best_ms(lambda: ring.put(data, frame=next(frame), timestamp_ns=0, fmt=stream), 1)
        )
        times["unpack"].append(
            best_ms(
                lambda: unpack(
                    data, fmt, width=width, height=height, stride=stream.stride, out=out
                ),
                1,
            )
        )
    best = {k: min(v) for k, v in times.items()}
    return {
        "frame_bytes": int(data.size),
        "copy_ms": round(best["copy"], 3),
        "place_ms": round(best["place"], 3),
        "unpack_ms": round(best["unpack"], 3),
        "place_vs_copy": round(best["place"] / best["copy"], 2),
        "unpack_vs_copy": round(best["unpack"] / best["copy"], 2),
        "place_target_max": 2.0,
    }


def streaming(seconds: float, fps: float) -> dict[str, Any]:
    """The board streaming a 5 MPix RAW10 synthetic node on one core."""
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    source_image = image(FIVE_MPIX, 1)

    def node(port: V4L2Port) -> SyntheticSource:
        return SyntheticSource(source_image, fourcc="pRAA", fps=fps, path=port.video)

    board = V4L2Board(["synthetic:5mpix"], open_source=node, ring_frames=8)
    try:
        board.capture(0, timeout_s=5)
        first = board.port_status(0)
        cpu0, wall0 = time.process_time(), time.monotonic()
        time.sleep(seconds)
        cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
        last = board.port_status(0)
    finally:
        board.close()
    frames = last["frames"] - first["frames"]
    return {
        "width": FIVE_MPIX[1],
        "height": FIVE_MPIX[0],
        "fps_asked": fps,
        "seconds": round(wall, 2),
        "frames": frames,
        "fps_kept": round(frames / wall, 2),
        "dropped": last["dropped"] - first["dropped"],
        "cpu_fraction_of_one_core": round(cpu / wall, 3),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=15)
    p.add_argument("--stream-s", type=float, default=8.0)
    p.add_argument("--fps", type=float, default=15.0)
    args = p.parse_args()
    result = {
        "bench": "v4l2",
        "peer": "numpy copyto of the same bytes into an existing array",
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "numpy": np.__version__,
        },
        "raw10_full_frame": placement(args.repeat),
        "stream_5mpix": streaming(args.stream_s, args.fps),
    }
    print(json.dumps(result, sort_keys=True))


if __name__ == "__main__":
    main()
