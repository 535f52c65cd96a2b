"""A simulated Lepton 3.5 speaking VoSPI at the spidev seam, with its timing and faults.

`SimVoSPIStream` is the Lepton's side of the SPI link in virtual time: a segment becomes
ready every 1/106 s; of every twelve, four are the segments 1-4 of a unique frame and
eight are invalid repeats (segment number 0), so unique frames come at 8.8 a second. A
host that clocks bytes while a segment is ready gets its packets, otherwise discard
packets. Time passes only as the host clocks bytes (164 bytes take 65.6 us at 20 MHz) or
deselects the device, so tests run ten simulated minutes in seconds.

`SimSpidev` is the spidev node the daemon's reader opens (`elphel_camd.vospi.SpiDevice`):
the real reader runs against it unchanged.

Faults (``sim_*``), each recorded in the truth with its time window:

* ``sim_crc_errors(rate)``: each video packet has one byte flipped with that probability;
* ``sim_lose_bytes(at_s, count)``: ``count`` bytes from ``at_s`` never reach the host, so
  what follows is off the packet boundaries until the host resynchronises;
* ``sim_stall(at_s, duration_s)``: no segments for a while (discard packets only);
* ``sim_lose_sync(at_s)``: garbage from ``at_s`` until the host deselects the device for
  more than 185 ms.

The truth (`SimVoSPIStream.truth`) lists every unique frame the Lepton made: its frame
counter, when its first and last packet went out, a digest of its pixels, whether a fault
touched it and whether the Lepton produced all its segments (not while stalled or out of
sync; a segment the host did not clock out because it was deselected still counts as
produced).
"""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from elphel_camd.sensors import cci
from elphel_camd.vospi import packets as vp
from elphel_camd.vospi import telemetry as tm

SEGMENT_RATE_HZ = 106.0
SEGMENTS_PER_CYCLE = 12  # a unique frame's 4 segments, then two invalid frames
RESYNC_IDLE_S = 0.185  # a deselect longer than this resynchronises the Lepton
TELEMETRY_REVISION = 14
MAX_BEHIND_S = 0.05  # a paced stream this far behind the wall clock goes on from there
_DISCARD = vp.discard_packet()

FrameSource = Callable[[int], NDArray[np.uint16]]


def telemetry_rows(
    *,
    frame_counter: int,
    uptime_ms: int,
    fpa_centi_k: int,
    frame_mean: int,
    ffc_state: int = 0,
    tlinear: bool = True,
    resolution_code: int = 1,
) -> NDArray[np.uint16]:
    """The two telemetry rows of a frame (layout: `elphel_camd.vospi.telemetry`)."""
    rows = np.zeros((tm.TELEMETRY_ROWS, vp.WIDTH), np.uint16)

    def put(at: tuple[int, int], words: list[int]) -> None:
        rows[at[0], at[1] : at[1] + len(words)] = words

    put(tm.REVISION, [TELEMETRY_REVISION])
    put(tm.UPTIME_MS, cci.words_of(uptime_ms & 0xFFFFFFFF, 2))
    put(tm.STATUS, cci.words_of((ffc_state & 0x3) << tm.FFC_STATE_SHIFT, 2))
    put(tm.FRAME_COUNTER, cci.words_of(frame_counter & 0xFFFFFFFF, 2))
    put(tm.FRAME_MEAN, [frame_mean & 0xFFFF])
    put(tm.FPA_TEMPERATURE_CENTI_K, [fpa_centi_k & 0xFFFF])
    put(tm.TLINEAR_ENABLED, [int(tlinear)])
    put(tm.TLINEAR_RESOLUTION, [resolution_code])
    return rows


def synthetic_frame(number: int, *, telemetry: bool = True) -> NDArray[np.uint16]:
    """A frame whose pixels differ from every other frame's (TLinear centi-kelvin).

    With telemetry the two footer rows carry ``number`` as the frame counter.
    """
    rng = np.random.default_rng(number)
    image = (29315 + rng.integers(0, 2000, (tm.HEIGHT, vp.WIDTH))).astype(np.uint16)
    if not telemetry:
        return image
    rows = telemetry_rows(
        frame_counter=number,
        uptime_ms=round(number * 1000 / 8.8),
        fpa_centi_k=30515,
        frame_mean=round(float(image.mean())),
        ffc_state=3,
    )
    return np.vstack([image, rows])


def segments_of(rows: NDArray[np.uint16]) -> list[bytes]:
    """The four segments (packets, concatenated) of a frame of 120 or 122 rows."""
    if rows.shape not in ((tm.HEIGHT, vp.WIDTH), (tm.HEIGHT + tm.TELEMETRY_ROWS, vp.WIDTH)):
        raise ValueError(f"a Lepton frame of shape {rows.shape}; allowed: (120|122, 160)")
    payloads = np.ascontiguousarray(rows, dtype=">u2").tobytes()
    per_segment = len(payloads) // vp.PAYLOAD_BYTES // vp.SEGMENTS_PER_FRAME
    out = []
    for s in range(vp.SEGMENTS_PER_FRAME):
        packets = []
        for n in range(per_segment):
            i = (s * per_segment + n) * vp.PAYLOAD_BYTES
            packets.append(vp.packet(vp.video_id(n, s + 1), payloads[i : i + vp.PAYLOAD_BYTES]))
        out.append(b"".join(packets))
    return out


def invalid_segment(segment: bytes) -> bytes:
    """The same packets with segment number 0 in packet 20 (an invalid repeat)."""
    at = vp.SEGMENT_NUMBER_PACKET * vp.PACKET_BYTES
    old = segment[at : at + vp.PACKET_BYTES]
    number = ((old[0] & 0x0F) << 8) | old[1]
    new = vp.packet(number, old[vp.HEADER_BYTES :])
    return segment[:at] + new + segment[at + vp.PACKET_BYTES :]


@dataclass
class FrameTruth:
    """One unique frame as the simulated Lepton sent it."""

    number: int
    digest: str
    due_s: float  # when its segment 1 was due; segment 4 is due 3 segment periods later
    first_s: float = math.inf
    last_s: float = -math.inf
    segments_sent: int = 0
    touched: bool = False
    produced: bool = True  # False: the Lepton was stalled or out of sync for a segment


@dataclass
class FaultTruth:
    """One injected fault: its kind and when it began and ended (virtual seconds)."""

    kind: str
    start_s: float
    end_s: float = math.nan


@dataclass
class _Pending:
    """Faults scheduled ahead, by virtual time."""

    lose: list[tuple[float, int]] = field(default_factory=list)
    stalls: list[tuple[float, float]] = field(default_factory=list)
    syncs: list[float] = field(default_factory=list)


def digest(image: NDArray[np.uint16]) -> str:
    """A digest of a frame's pixels (image rows only)."""
    return hashlib.blake2b(
        np.ascontiguousarray(image, np.uint16).tobytes(), digest_size=16
    ).hexdigest()


class SimVoSPIStream:
    """The Lepton's end of the SPI link, in virtual time (see the module docstring).

    Parameters
    ----------
    frame_source
        The rows of unique frame ``n`` (from 1): 120 x 160, or 122 x 160 with telemetry.
    seed
        Seed of the fault draws (which packets are corrupted, the garbage bytes).
    clock_hz
        The SPI clock the host runs (`SimSpidev` sets it).
    """

    def __init__(
        self,
        frame_source: FrameSource = synthetic_frame,
        *,
        seed: int = 0,
        clock_hz: int = 20_000_000,
    ) -> None:
        self.frame_source = frame_source
        self.clock_hz = clock_hz
        self.t = 0.0
        self.truth: dict[int, FrameTruth] = {}
        self.faults: list[FaultTruth] = []
        self.crc_rate = 0.0
        self.bytes_sent = 0
        self._rng = np.random.default_rng(seed)
        self._next_k = 0
        self._sending: bytes | None = None
        self._sending_k = -1
        self._offset = 0
        self._carry = bytearray()
        self._lose_left = 0
        self._garbage = False
        self._pending = _Pending()
        self._stall: tuple[float, float] | None = None
        self._off: list[tuple[float, float]] = []  # when the Lepton sent no segments
        self._frame_k = -1  # the unique frame whose segments are cached
        self._segments: list[bytes] = []

    # -- faults ----------------------------------------------------------------------------

    def sim_crc_errors(self, rate: float) -> None:
        """From now on, each video packet has one CRC-covered bit flipped with this probability."""
        if not 0.0 <= rate <= 1.0:
            raise ValueError(f"rate={rate}; allowed: 0..1")
        self.crc_rate = rate

    def sim_lose_bytes(self, at_s: float, count: int) -> None:
        """``count`` bytes sent from ``at_s`` on never reach the host."""
        self._pending.lose.append((at_s, count))

    def sim_stall(self, at_s: float, duration_s: float) -> None:
        """No segments from ``at_s`` for ``duration_s`` (discard packets only)."""
        self._pending.stalls.append((at_s, duration_s))

    def sim_lose_sync(self, at_s: float) -> None:
        """Garbage from ``at_s`` until the host deselects the device for more than 185 ms."""
        self._pending.syncs.append(at_s)

    def _start_due_faults(self) -> None:
        p, t = self._pending, self.t
        for lose in [x for x in p.lose if x[0] <= t]:
            p.lose.remove(lose)
            self._lose_left += lose[1]
            self.faults.append(FaultTruth("lost_bytes", t))
        for stall in [x for x in p.stalls if x[0] <= t]:
            p.stalls.remove(stall)
            self._stall = (t, t + stall[1])
            self._off.append(self._stall)
            self.faults.append(FaultTruth("stall", t, t + stall[1]))
        for at in [x for x in p.syncs if x <= t]:
            p.syncs.remove(at)
            self._garbage = True
            self.faults.append(FaultTruth("lost_sync", t))

    # -- the host's side -------------------------------------------------------------------

    def read(self, size: int) -> bytes:
        """Clock ``size`` bytes out of the Lepton (virtual time passes)."""
        while len(self._carry) < size:
            self._carry += self._produce(size - len(self._carry))
        out = bytes(self._carry[:size])
        del self._carry[:size]
        return out

    def idle(self, seconds: float) -> None:
        """Hold /CS high for ``seconds``.

        A segment being sent is abandoned and the next transfer starts on a packet
        boundary; longer than 185 ms resynchronises the Lepton (cures lost sync).
        """
        self.t += seconds
        self._sending = None
        self._carry.clear()
        self._lose_left = 0
        open_lost = [f for f in self.faults if f.kind == "lost_bytes" and math.isnan(f.end_s)]
        for f in open_lost:
            f.end_s = self.t
        if seconds > RESYNC_IDLE_S and self._garbage:
            self._garbage = False
            for f in self.faults:
                if f.kind == "lost_sync" and math.isnan(f.end_s):
                    f.end_s = self.t
                    self._off.append((f.start_s, f.end_s))

    def _advance(self, data: bytes) -> bytes:
        """Time passes for the bytes sent; bytes being lost are taken out."""
        self.t += len(data) * 8 / self.clock_hz
        self.bytes_sent += len(data)
        if not self._lose_left:
            return data
        lost = min(self._lose_left, len(data))
        self._lose_left -= lost
        if not self._lose_left:
            for f in self.faults:
                if f.kind == "lost_bytes" and math.isnan(f.end_s):
                    f.end_s = self.t
        return data[lost:]

    def _produce(self, want: int) -> bytes:
        self._start_due_faults()
        if self._garbage:
            count = max(want, vp.PACKET_BYTES)
            return self._advance(self._rng.bytes(count))
        if self._sending is None:
            self._next_segment()
        if self._sending is None:
            due_s = self._next_k / SEGMENT_RATE_HZ
            packets = math.ceil((due_s - self.t) * self.clock_hz / 8 / vp.PACKET_BYTES)
            packets = max(1, min(packets, math.ceil(want / vp.PACKET_BYTES)))
            return self._advance(_DISCARD * packets)
        packets = max(1, math.ceil(want / vp.PACKET_BYTES))
        start, k, start_s = self._offset, self._sending_k, self.t
        chunk = self._sending[start : start + packets * vp.PACKET_BYTES]
        self._offset += len(chunk)
        done = self._offset >= len(self._sending)
        if done:
            self._sending = None
        hit = bool(self._lose_left)
        out = self._advance(chunk)
        self._mark_sent(k, start_s=start_s if start == 0 else None, last=done, hit=hit)
        return out

    def _mark_sent(self, k: int, *, start_s: float | None, last: bool, hit: bool) -> None:
        if k % SEGMENTS_PER_CYCLE >= vp.SEGMENTS_PER_FRAME:
            return
        truth = self.truth[k // SEGMENTS_PER_CYCLE + 1]
        if start_s is not None:
            truth.first_s = min(truth.first_s, start_s)
        if last:
            truth.last_s = self.t
            truth.segments_sent += 1
        truth.touched = truth.touched or hit

    def _next_segment(self) -> None:
        due = math.floor(self.t * SEGMENT_RATE_HZ + 1e-9)
        if due < self._next_k:
            return
        for k in range(self._next_k, due):  # due while the host was not clocking
            self._skipped(k)
        self._next_k = due + 1
        if self._stall is not None:
            if self.t < self._stall[1]:
                self._skipped(due)
                return
            self._stall = None
        self._sending, self._sending_k, self._offset = self._segment(due), due, 0

    def _skipped(self, k: int) -> None:
        """Segment ``k`` was not sent: the Lepton was off (stall, lost sync) or the host idle."""
        frame_k, position = divmod(k, SEGMENTS_PER_CYCLE)
        if position >= vp.SEGMENTS_PER_FRAME:
            return
        truth = self._frame_truth(frame_k)
        t = k / SEGMENT_RATE_HZ
        if any(start <= t <= end for start, end in self._off):
            truth.produced = False

    def _frame_truth(self, frame_k: int) -> FrameTruth:
        """The truth of unique frame ``frame_k + 1``, its segments made ready to send."""
        if frame_k != self._frame_k:
            rows = self.frame_source(frame_k + 1)
            self._segments = segments_of(rows)
            due_s = frame_k * SEGMENTS_PER_CYCLE / SEGMENT_RATE_HZ
            self.truth[frame_k + 1] = FrameTruth(frame_k + 1, digest(rows[: tm.HEIGHT]), due_s)
            self._frame_k = frame_k
        return self.truth[frame_k + 1]

    def _segment(self, k: int) -> bytes:
        frame_k, position = divmod(k, SEGMENTS_PER_CYCLE)
        self._frame_truth(frame_k)
        data = self._segments[position % vp.SEGMENTS_PER_FRAME]
        if position >= vp.SEGMENTS_PER_FRAME:
            data = invalid_segment(data)
        return self._corrupt(data, frame_k + 1 if position < vp.SEGMENTS_PER_FRAME else None)

    def _corrupt(self, data: bytes, frame: int | None) -> bytes:
        count = len(data) // vp.PACKET_BYTES
        hits = int(self._rng.binomial(count, self.crc_rate)) if self.crc_rate else 0
        if not hits:
            return data
        out = bytearray(data)
        for packet in self._rng.choice(count, size=hits, replace=False):
            # A CRC-covered bit: the ID's low 12 bits, the CRC field or the payload.
            bit = int(self._rng.integers(4, vp.PACKET_BYTES * 8))
            out[int(packet) * vp.PACKET_BYTES + bit // 8] ^= 0x80 >> (bit % 8)
        if frame is not None:
            self.truth[frame].touched = True
        self.faults.append(FaultTruth("crc", self.t, self.t))
        return bytes(out)


class SimSpidev:
    """A spidev node with a simulated Lepton behind it (`elphel_camd.vospi.SpiDevice`).

    Parameters
    ----------
    stream
        The Lepton's end of the link.
    path
        The node's name in messages.
    sim_forced_mode
        An SPI mode the controller keeps whatever is asked (None: it takes the one asked).
        Data clocked in a mode other than 3 arrive one bit late.
    time_scale
        Virtual seconds per wall-clock second: transfers and deselects wait so that the
        Lepton's time does not run ahead (None: as fast as the host reads, for tests).
        When it fell more than `MAX_BEHIND_S` behind (a slow host, slow frames), it goes
        on from where it is instead of racing to catch up.
    """

    def __init__(
        self,
        stream: SimVoSPIStream,
        *,
        path: str = "/dev/spidev0.0",
        sim_forced_mode: int | None = None,
        time_scale: float | None = None,
    ) -> None:
        self.stream = stream
        self.path = path
        self.sim_forced_mode = sim_forced_mode
        self.time_scale = time_scale
        self._origin = (time.monotonic(), stream.t)
        self._mode = 0
        self.closed = False
        self.transfers = 0
        self.idles: list[float] = []

    def set_mode(self, mode: int) -> None:
        self._mode = mode if self.sim_forced_mode is None else self.sim_forced_mode

    def mode(self) -> int:
        return self._mode

    def set_max_speed_hz(self, hz: int) -> None:
        self.stream.clock_hz = hz

    def max_speed_hz(self) -> int:
        return self.stream.clock_hz

    def read(self, size: int) -> bytes:
        self.transfers += 1
        data = self.stream.read(size)
        self._keep_pace()
        if self._mode & 0x3 == 3:
            return data
        value = int.from_bytes(data, "big") >> 1  # sampled on the wrong edge: a bit late
        return value.to_bytes(len(data), "big")

    def idle(self, seconds: float) -> None:
        self.idles.append(seconds)
        self.stream.idle(seconds)
        self._keep_pace()

    def _keep_pace(self) -> None:
        if self.time_scale is None:
            return
        wall, virtual = self._origin
        now = time.monotonic()
        ahead_s = wall + (self.stream.t - virtual) / self.time_scale - now
        if ahead_s > 0:
            time.sleep(ahead_s)
        elif ahead_s < -MAX_BEHIND_S:
            self._origin = (now, self.stream.t)

    def now_ns(self) -> int:
        return round(self.stream.t * 1e9)

    def close(self) -> None:
        self.closed = True
