"""The VoSPI reader against the simulated Lepton: ten simulated minutes of faults, replay.

The simulated Lepton (`elphel_sim.vospi`) keeps its own truth: every unique frame it sent,
when, a digest of its pixels and whether a fault touched it. The reader's frames are
checked against that truth, never against the reader's own view.
"""

import io
import math

import numpy as np
import pytest

from elphel_camd.vospi import FileSource, SpidevSource, VoSPIReader
from elphel_sim.vospi import (
    SEGMENT_RATE_HZ,
    SEGMENTS_PER_CYCLE,
    SimSpidev,
    SimVoSPIStream,
    digest,
)

MINUTES = 10
RECOVERY_S = 0.3  # the stream must be back this long after a fault ends
SEGMENT_S = 1 / SEGMENT_RATE_HZ
CYCLE_S = SEGMENTS_PER_CYCLE * SEGMENT_S  # from one unique frame to the next
WINDOWED = ("lost_bytes", "stall", "lost_sync")
SEGMENTS = 4


def faulty_stream(seed: int, minutes: int) -> SimVoSPIStream:
    """1 CRC error per 1000 packets, a lost stretch a minute, a stall and a lost sync
    every five minutes, at random times."""
    rng = np.random.default_rng(seed)
    stream = SimVoSPIStream(seed=seed)
    stream.sim_crc_errors(1e-3)
    for minute in range(minutes):
        stream.sim_lose_bytes(60 * minute + rng.uniform(1, 59), int(rng.integers(1, 4000)))
        if minute % 5 == 2:
            stream.sim_stall(60 * minute + rng.uniform(1, 50), rng.uniform(0.5, 3.0))
        if minute % 5 == 4:
            stream.sim_lose_sync(60 * minute + rng.uniform(1, 59))
    return stream


def run(stream: SimVoSPIStream, seconds: float, record=None):
    reader = VoSPIReader(SpidevSource(SimSpidev(stream), bufsiz=4096), record=record)
    frames = []
    while stream.t < seconds:
        frames.append(reader.read_frame(timeout_s=5))
    return reader, frames


def first_clean_after(fault, truths):
    """The first frame untouched by any fault that the Lepton began one segment period or
    more after the fault ended, and how many touched frames it began after the fault."""
    later = sorted((t for t in truths if t.due_s >= fault.end_s + SEGMENT_S), key=lambda t: t.due_s)
    clean = [t for t in later if not t.touched and t.produced]
    first = clean[0]
    return first, sum(t.touched for t in later if t.due_s < first.due_s)


def recovery_s(fault, truths, delivered) -> float:
    """When the stream is back after a fault: the end of the first clean frame sent after
    it, which the reader must deliver (frames CRC errors touched in between are the
    Lepton's loss, a frame cycle each, not the reader's)."""
    first, touched = first_clean_after(fault, truths)
    assert first.number in delivered, (
        f"{fault.kind} at {fault.start_s:.3f} s: the first clean frame after it, "
        f"{first.number}, sent {first.due_s - fault.end_s:.3f} s after its end, was lost"
    )
    return first.last_s - fault.end_s - touched * CYCLE_S


def excused(truth, faults) -> bool:
    """A frame a fault touched, or sent within a windowed fault or the recovery after it."""
    if truth.touched or not truth.produced:
        return True
    start_s = truth.due_s
    end_s = max(truth.last_s, start_s + SEGMENTS / SEGMENT_RATE_HZ)
    return any(
        f.kind in WINDOWED and end_s >= f.start_s and start_s <= f.end_s + RECOVERY_S
        for f in faults
    )


@pytest.mark.slow
def test_ten_minutes_of_faults_give_no_torn_frame_and_lose_no_untouched_one():
    stream = faulty_stream(seed=39, minutes=MINUTES)
    reader, frames = run(stream, MINUTES * 60)
    numbers = [f.number for f in frames]
    assert numbers == sorted(set(numbers)), "a frame came twice or out of order"
    altered = [f.number for f in frames if stream.truth[f.number].digest != digest(f.image)]
    assert altered == []
    delivered = set(numbers)
    faults = [f for f in stream.faults if f.kind in WINDOWED]
    assert all(not math.isnan(f.end_s) for f in faults)
    assert len([f for f in faults if f.kind == "lost_bytes"]) == MINUTES
    assert len([f for f in faults if f.kind == "stall"]) == MINUTES // 5
    expected = {n for n, t in stream.truth.items() if not excused(t, stream.faults)}
    missing = sorted(expected - delivered)
    assert missing == [], f"{len(missing)} untouched frames not delivered: {missing[:10]}"
    # The run means something: most frames are untouched (0.999 ** 244 = 78 %), and
    # after every windowed fault the Lepton went on making frames (which then had to be
    # delivered).
    assert len(expected) > 0.7 * len(stream.truth)
    for f in faults:
        after = [t.due_s for t in stream.truth.values() if t.due_s > f.end_s + RECOVERY_S]
        assert min(after) < f.end_s + RECOVERY_S + SEGMENTS_PER_CYCLE / SEGMENT_RATE_HZ
    assert reader.counts.crc_errors > 1000
    recovery = [recovery_s(f, stream.truth.values(), delivered) for f in faults]
    assert max(recovery) <= RECOVERY_S, recovery
    # Lost sync ends when the reader deselects the Lepton: it must see the loss at once.
    assert all(f.end_s - f.start_s < RECOVERY_S for f in faults if f.kind == "lost_sync")


def test_a_recording_replays_into_the_same_frames_bit_for_bit(tmp_path):
    stream = faulty_stream(seed=7, minutes=1)
    record = io.BytesIO()
    reader, live = run(stream, 60, record=record)
    reader.close_record()
    path = tmp_path / "lepton.vospi"
    path.write_bytes(record.getvalue())
    replay = VoSPIReader(FileSource(str(path)))
    again = []
    with pytest.raises(EOFError):
        while True:
            again.append(replay.read_frame(timeout_s=5))
    assert len(live) > 400
    assert [f.number for f in again] == [f.number for f in live]
    for a, b in zip(again, live, strict=True):
        assert np.array_equal(a.image, b.image)
        assert a.telemetry == b.telemetry
