"""Packets into segments into frames, keeping only whole frames of one readout.

`FrameAssembler` takes the video packets that passed their CRC, in the order they came,
and hands out a frame only when segments 1, 2, 3 and 4 arrived one after the other, each
complete with consecutive packet numbers and all with the same packet count (60, or 61
with telemetry). Anything else drops what was being assembled: a torn frame cannot come
out. Segments numbered 0 (the invalid repeats a Lepton 3 sends between unique frames)
are counted and dropped.

The packet count is learnt from the stream. Until it is known, a segment that reached
packet 59 is complete at the next video packet: packet 60 makes it 61 packets long, a
packet 0 makes it 60. From then on a segment is complete at its last packet under the
count in use. A packet 60 after a 60-packet segment (telemetry switched on) changes the
count and drops the frame being assembled. A packet 0 after packet 59 of a 61-packet
segment (telemetry switched off) changes the count too: that segment is complete with 60
packets, and only the segments before it are dropped.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

from elphel_camd.vospi.packets import (
    PACKETS_PER_SEGMENT,
    PACKETS_PER_SEGMENT_TELEMETRY,
    SEGMENT_NUMBER_PACKET,
    SEGMENTS_PER_FRAME,
)


class Outcome(Enum):
    """What one packet did to the assembly."""

    NONE = 0  # taken, nothing completed
    SEGMENT = 1  # completed a segment (valid or invalid)
    FRAME = 2  # completed a frame: take it with `FrameAssembler.take`
    DROPPED = 3  # completed a segment out of order: the frame in progress is dropped
    BROKEN = 4  # a packet out of order: what was being assembled is dropped


@dataclass
class AssemblyCounts:
    """What the assembler has seen (cumulative)."""

    segments_valid: int = 0
    segments_invalid: int = 0
    frames: int = 0
    frames_dropped: int = 0
    out_of_order: int = 0
    telemetry_switches: int = 0


@dataclass
class FrameAssembler:
    """Video packets -> whole frames (see the module docstring)."""

    packets_per_segment: int | None = None
    counts: AssemblyCounts = field(default_factory=AssemblyCounts)

    def __post_init__(self) -> None:
        self._segment: list[bytes] = []
        self._expect = 0  # next packet number; -1: waiting for a packet 0
        self._number = 0  # segment number from packet 20
        self._frame: list[bytes] = []  # payloads of segments 1..k of the frame in progress
        self._segments = 0  # segments in self._frame
        self._done: list[bytes] | None = None
        self._after_last = False  # the previous video packet ended a segment

    def reset(self) -> None:
        """Drop the segment and the frame in progress; wait for the next packet 0."""
        if self._segments:
            self.counts.frames_dropped += 1
        self._segment, self._frame, self._segments = [], [], 0
        self._expect = -1
        self._after_last = False

    def take(self) -> bytes:
        """The payload bytes of the frame just completed."""
        if self._done is None:
            raise LookupError("no VoSPI frame is complete")
        done, self._done = self._done, None
        return b"".join(done)

    def push(self, number: int, segment: int, payload: bytes) -> Outcome:
        """Take one video packet (CRC good): its number, ID segment bits and payload.

        While waiting for a segment start (after a drop), packets other than 0 are the
        rest of a segment already given up and are passed over.
        """
        outcome = Outcome.NONE
        if self._after_last:
            self._after_last = False
            if number == PACKETS_PER_SEGMENT == self.packets_per_segment:
                self._switch(PACKETS_PER_SEGMENT_TELEMETRY)
                return self._broken(wait=True)
        if number != self._expect:
            if number != 0:
                return Outcome.NONE if self._expect < 0 else self._broken(wait=True)
            if self._expect == PACKETS_PER_SEGMENT:  # packet 0 after 59: 60 a segment
                if self.packets_per_segment == PACKETS_PER_SEGMENT_TELEMETRY:
                    self._switch(PACKETS_PER_SEGMENT)
                    self._drop_frame()  # its segments had 61 packets
                self.packets_per_segment = PACKETS_PER_SEGMENT
                outcome = self._segment_done()
            elif self._expect > 0:
                outcome = self._broken(wait=False)
            self._segment, self._expect = [], 0
        self._segment.append(payload)
        if number == SEGMENT_NUMBER_PACKET:
            self._number = segment
        self._expect = number + 1
        if self.packets_per_segment is None and self._expect == PACKETS_PER_SEGMENT_TELEMETRY:
            self.packets_per_segment = PACKETS_PER_SEGMENT_TELEMETRY
        if self._expect == self.packets_per_segment:
            self._expect = 0
            self._after_last = True
            return self._segment_done()
        return outcome

    def _switch(self, packets: int) -> None:
        self.packets_per_segment = packets
        self.counts.telemetry_switches += 1

    def _broken(self, *, wait: bool) -> Outcome:
        self.counts.out_of_order += 1
        if self._segments:
            self.counts.frames_dropped += 1
        self._segment, self._frame, self._segments = [], [], 0
        self._expect = -1 if wait else 0
        return Outcome.BROKEN

    def _drop_frame(self) -> None:
        if self._segments:
            self.counts.frames_dropped += 1
        self._frame, self._segments = [], 0

    def _dropped(self) -> Outcome:
        """A whole segment out of order: drop the frame in progress (sync is fine)."""
        self.counts.out_of_order += 1
        if self._segments:
            self.counts.frames_dropped += 1
        self._frame, self._segments = [], 0
        return Outcome.DROPPED

    def _segment_done(self) -> Outcome:
        number, payloads = self._number, self._segment
        self._segment, self._number = [], 0
        if number == 0:
            self.counts.segments_invalid += 1
            return self._dropped() if self._segments else Outcome.SEGMENT
        self.counts.segments_valid += 1
        if number == 1:
            if self._segments:
                self.counts.frames_dropped += 1
            self._frame, self._segments = [], 0
        elif number != self._segments + 1 or number > SEGMENTS_PER_FRAME:
            return self._dropped()
        self._frame.extend(payloads)
        self._segments += 1
        if self._segments < SEGMENTS_PER_FRAME:
            return Outcome.SEGMENT
        self._done, self._frame, self._segments = self._frame, [], 0
        self.counts.frames += 1
        return Outcome.FRAME
