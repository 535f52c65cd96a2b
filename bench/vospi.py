"""VoSPI benchmark: the reader's CPU at a Lepton 3's full segment rate, against pylepton's way.

Records SECONDS of the simulated Lepton's byte stream (`elphel_sim.vospi`: 106 segments
a second, invalid repeats, discard packets between segments, read at 20 MHz in transfers
of 24 packets as spidev's default bufsiz allows), with one CRC error per 1000 video
packets, then in the same run parses the same transfers
- with `elphel_camd.vospi.VoSPIReader` (CRC on every packet, whole frames only), and
- with pylepton's approach to the Lepton 3 (re-implemented here from its described
  behaviour): wait for a segment numbered 1, then take the next 180 video packets as
  segments 2-4, fixed counts, no CRC, no segment numbers checked.
Reports CPU seconds per second of stream (a fraction of one core), frames delivered, and
frames whose pixels differ from what the simulated Lepton sent (torn or altered).
Prints exactly one JSON object.

    .venv/bin/python bench/vospi.py [--seconds 30 --repeat 3]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from typing import Any

import numpy as np

from elphel_camd.vospi import VoSPIReader
from elphel_camd.vospi import packets as vp
from elphel_sim.vospi import SimVoSPIStream, digest, synthetic_frame

TRANSFER_BYTES = 24 * vp.PACKET_BYTES  # spidev's default bufsiz (4096) in whole packets
CPU_LIMIT = 0.10


class Transfers:
    """A recorded list of transfers, served as a spidev source serves its reads."""

    realigns_on_deselect = True
    hunt_limit_bytes = 2 * vp.PACKET_BYTES

    def __init__(self, chunks: list[bytes]) -> None:
        self.path = "recorded transfers"
        self.chunks, self.at = chunks, 0

    def read(self, timeout_s: float) -> bytes:
        if self.at == len(self.chunks):
            return b""
        self.at += 1
        return self.chunks[self.at - 1]

    def deselect(self, seconds: float) -> None:
        pass

    def now_ns(self) -> int:
        return self.at

    def close(self) -> None:
        pass


def record(seconds: float, seed: int) -> tuple[list[bytes], SimVoSPIStream]:
    stream = SimVoSPIStream(lambda n: synthetic_frame(n, telemetry=False), seed=seed)
    stream.sim_crc_errors(1e-3)
    chunks = []
    while stream.t < seconds:
        chunks.append(stream.read(TRANSFER_BYTES))
    return chunks, stream


def ours(chunks: list[bytes]) -> list[np.ndarray]:
    reader = VoSPIReader(Transfers(chunks))
    frames = []
    try:
        while True:
            frames.append(reader.read_frame().image)
    except EOFError:
        return frames


def pylepton_way(chunks: list[bytes]) -> list[np.ndarray]:
    """Segment 1 found by packet 20's number, then 180 more video packets, unchecked."""
    frames, payloads, waiting = [], [], True
    for chunk in chunks:
        for at in range(0, len(chunk), vp.PACKET_BYTES):
            if chunk[at] & 0x0F == 0x0F:
                continue
            number = ((chunk[at] & 0x0F) << 8) | chunk[at + 1]
            if waiting:
                if number == 0:
                    payloads = []
                payloads.append(chunk[at + 4 : at + vp.PACKET_BYTES])
                if number == vp.SEGMENT_NUMBER_PACKET and chunk[at] >> 4 & 0x7 == 1:
                    waiting = False
                continue
            payloads.append(chunk[at + 4 : at + vp.PACKET_BYTES])
            if len(payloads) == 240:
                data = b"".join(payloads)
                frames.append(np.frombuffer(data, ">u2").astype(np.uint16).reshape(120, 160))
                payloads, waiting = [], True
    return frames


def measure(fn: Any, chunks: list[bytes], repeat: int) -> tuple[float, list[np.ndarray]]:
    best, frames = float("inf"), []
    for _ in range(repeat):
        t = time.process_time()
        frames = fn(chunks)
        best = min(best, time.process_time() - t)
    return best, frames


def judged(frames: list[np.ndarray], stream: SimVoSPIStream) -> dict[str, int]:
    sent = {t.digest for t in stream.truth.values()}
    altered = sum(digest(f) not in sent for f in frames)
    return {"frames": len(frames), "altered": altered}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--seed", type=int, default=39)
    args = p.parse_args()
    chunks, stream = record(args.seconds, args.seed)
    ours_s, ours_frames = measure(ours, chunks, args.repeat)
    peer_s, peer_frames = measure(pylepton_way, chunks, args.repeat)
    untouched = sum(not t.touched and t.produced for t in stream.truth.values())
    ours_fraction = ours_s / stream.t
    print(
        json.dumps(
            {
                "benchmark": "vospi",
                "python": platform.python_version(),
                "stream_s": round(stream.t, 3),
                "segments_per_s": 106,
                "transfer_bytes": TRANSFER_BYTES,
                "crc_error_rate": stream.crc_rate,
                "unique_frames_sent": len(stream.truth),
                "untouched_frames_sent": untouched,
                "ours": {
                    "cpu_s": round(ours_s, 4),
                    "cpu_fraction_of_core": round(ours_fraction, 4),
                    **judged(ours_frames, stream),
                },
                "pylepton_approach": {
                    "cpu_s": round(peer_s, 4),
                    "cpu_fraction_of_core": round(peer_s / stream.t, 4),
                    **judged(peer_frames, stream),
                },
                "cpu_ratio_ours_to_pylepton": round(ours_s / peer_s, 3),
                "cpu_limit_fraction": CPU_LIMIT,
                "within_limit": ours_fraction <= CPU_LIMIT,
            }
        )
    )


if __name__ == "__main__":
    main()
