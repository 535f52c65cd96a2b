"""Whole Lepton frames from a VoSPI byte stream, with resynchronisation.

`VoSPIReader` cuts the bytes of a `ByteSource` into 164-byte packets, skips discard
packets, checks the CRC of every other packet and feeds the good ones to a
`FrameAssembler`, which hands out a frame only when its four segments came whole and in
order. Recovery has two levels:

* a bad packet (CRC mismatch) or an out-of-order one drops what was being assembled; the
  reader stays at its packet alignment and re-locks at the next segment start;
* three bad packets in a row mean the packet alignment is lost (bytes went missing): the
  reader realigns, hunting in the bytes for a packet with a good CRC (or a discard packet)
  followed by one that agrees with it. The device is not deselected, so the next segment
  the Lepton sends is taken;
* sync is lost when the hunt finds no alignment within the source's hunting limit, when
  `REALIGNS_BEFORE_RESYNC` realignments brought no good packet, or when no segment (valid
  or invalid) came within `LOST_AFTER_PACKETS` packets. The reader then resynchronises:
  the source deselects the device for `RESYNC_IDLE_S` (/CS high, SCK idle: more than the
  185 ms a Lepton needs) and the reader hunts again. A Lepton that still sends only discard
  packets after that has stalled rather than lost sync: it is deselected again only every
  `STALLED_RESYNC_PACKETS` packets, so that the reader is reading when it starts again.

Every decision depends on the bytes alone (counts of packets, never clock time), so a
recording of the bytes the reader consumed (``record``) replays through a file source into
the same frames. The bytes a spidev source drops at a resync (read before the deselect,
stale after it) are not recorded.
"""

from __future__ import annotations

from binascii import crc_hqx
from dataclasses import dataclass, field
from typing import BinaryIO

import numpy as np
from numpy.typing import NDArray

from elphel_camd.vospi import telemetry as tm
from elphel_camd.vospi.errors import NotVoSPIError, VoSPITimeoutError
from elphel_camd.vospi.packets import (
    DISCARD_NIBBLE,
    HEADER_CRC,
    PACKET_BYTES,
    PACKETS_PER_SEGMENT,
    SEGMENT_MASK,
    WIDTH,
    crc_ok,
    is_discard,
)
from elphel_camd.vospi.segments import FrameAssembler, Outcome
from elphel_camd.vospi.sources import ByteSource

RESYNC_IDLE_S = 0.186
BAD_BEFORE_RESYNC = 3
# Realignments in a row without a good packet before a resync: pixel bytes can look like
# a pair of discard packets (a low nibble F, 1 in 256 byte positions), so a hunt may lock
# wrongly and need another.
REALIGNS_BEFORE_RESYNC = 3
# About four segment periods of packets read at 20 MHz (a segment is due every 9.4 ms,
# a packet takes 66 us): a Lepton in sync sends a segment, valid or not, far sooner.
LOST_AFTER_PACKETS = 600
# Packets of a stalled stream (discard packets only, also after a resync) between further
# resyncs: about 5 s at 20 MHz.
STALLED_RESYNC_PACKETS = 76_000
MAX_BUFFER_BYTES = 1 << 20
# A stream that never showed a good packet is not VoSPI after this many bytes other than
# discard packets, or this many resynchronisations for want of a packet alignment.
NOT_VOSPI_BYTES = 64 * 1024
NOT_VOSPI_RESYNCS = 5


@dataclass(frozen=True)
class VoSPIFrame:
    """One whole frame from a Lepton.

    Attributes
    ----------
    image
        The 120 x 160 pixels as sent (TLinear counts, or 14-bit raw counts).
    number
        The Lepton's frame counter (telemetry on), else the previous frame's number + 1
        (so numbers keep rising when telemetry is turned off).
    timestamp_ns
        When its last packet was read (the source's clock).
    telemetry
        The decoded telemetry rows, or None without telemetry.
    telemetry_rows
        The two raw telemetry rows, or None.
    """

    image: NDArray[np.uint16]
    number: int
    timestamp_ns: int
    telemetry: tm.Telemetry | None = None
    telemetry_rows: NDArray[np.uint16] | None = None


@dataclass
class ReaderCounts:
    """What the reader has seen (cumulative)."""

    packets: int = 0
    discard: int = 0
    crc_errors: int = 0
    realigns: int = 0
    resyncs: int = 0
    bytes_skipped: int = 0
    bytes_dropped: int = 0
    good_packets: int = 0
    reasons: dict[str, int] = field(default_factory=dict)


class VoSPIReader:
    """Whole frames from a VoSPI byte source.

    Parameters
    ----------
    source
        Where the bytes come from (a spidev device, a file or FIFO, a simulated Lepton).
    telemetry_location
        Where the telemetry rows sit when the stream has them: `telemetry.FOOTER` (the
        Lepton's power-on default) or `telemetry.HEADER`.
    record
        A binary file that receives every byte the reader consumes (a recording that
        replays into the same frames).
    """

    def __init__(
        self,
        source: ByteSource,
        *,
        telemetry_location: int = tm.FOOTER,
        record: BinaryIO | None = None,
    ) -> None:
        self.source = source
        self.telemetry_location = telemetry_location
        self.record = record
        self.assembler = FrameAssembler()
        self.counts = ReaderCounts()
        self.frames = 0
        self.number = 0  # of the last frame: frames without telemetry count on from it
        self.last_segment_ns: int | None = None
        self.ended = False
        self._buf = bytearray()
        self._pos = 0
        self._hunting = True
        self._hunted = 0
        self._bad = 0
        self._realigns = 0  # realignments since the last good packet
        self._silent_resyncs = 0  # resyncs since the last completed segment
        self._since = 0  # packets since the last completed segment
        self._drop = False  # buffered bytes went stale at a resync

    # -- reading ---------------------------------------------------------------------------

    def read_frame(self, timeout_s: float | None = None) -> VoSPIFrame:
        """The next whole frame.

        Raises `VoSPITimeoutError` when none came within ``timeout_s`` (of the source's
        clock) and EOFError at the end of a file.
        """
        start = self.source.now_ns()
        while True:
            frame = self._parse()
            if self._drop:
                self._drop_stale()
            if frame is not None:
                return frame
            waited_s = (self.source.now_ns() - start) / 1e9
            if timeout_s is not None and waited_s >= timeout_s:
                raise VoSPITimeoutError(self._timeout_message(waited_s))
            wait_s = 0.1 if timeout_s is None else min(0.1, timeout_s - waited_s)
            chunk = self.source.read(wait_s)
            if chunk is None:
                continue
            if not chunk:
                self.ended = True
                self.close_record()
                raise EOFError(f"{self.source.path}: end of the VoSPI stream")
            self._feed(chunk)

    def _timeout_message(self, waited_s: float) -> str:
        what = (
            "no bytes"
            if not self.counts.packets
            else "only discard packets"
            if self.counts.discard == self.counts.packets
            else "no whole frame"
        )
        return (
            f"{self.source.path}: {what} from the Lepton in {waited_s:.1f} s "
            f"({self.counts.resyncs} resyncs): check its power, /CS wiring and the device path"
        )

    def _feed(self, chunk: bytes) -> None:
        if self._pos:
            self._tap(self._pos)
            del self._buf[: self._pos]
            self._pos = 0
        self._buf += chunk
        if len(self._buf) > MAX_BUFFER_BYTES:  # cannot happen with whole-packet parsing
            raise ValueError(f"VoSPI buffer over {MAX_BUFFER_BYTES} bytes")

    def _tap(self, upto: int) -> None:
        if self.record is not None and upto:
            self.record.write(self._buf[:upto])

    def close_record(self) -> None:
        """Write the consumed bytes still buffered to the recording and flush it."""
        if self.record is not None:
            self._tap(self._pos)
            del self._buf[: self._pos]
            self._pos = 0
            self.record.flush()

    # -- parsing ---------------------------------------------------------------------------

    def _parse(self) -> VoSPIFrame | None:
        buf, end = self._buf, len(self._buf)
        view = memoryview(buf)
        try:
            while end - self._pos >= PACKET_BYTES:
                if self._hunting:
                    if not self._hunt(end):
                        break
                    continue
                frame = self._packet(buf, view)
                if frame is not None:
                    return frame
                if self._since > self._silence_limit():
                    self._silent_resyncs += 1
                    self.resync("no segment")
                elif self._bad >= BAD_BEFORE_RESYNC:
                    self._bad_packets()
                if self._drop:
                    return None
            return None
        finally:
            view.release()

    def _packet(self, buf: bytearray, view: memoryview) -> VoSPIFrame | None:
        """Take the packet at the read position (locked); return a completed frame."""
        pos = self._pos
        self._pos = pos + PACKET_BYTES
        self.counts.packets += 1
        self._since += 1
        hi = buf[pos]
        if hi & DISCARD_NIBBLE == DISCARD_NIBBLE:
            self.counts.discard += 1
            return None
        low12 = ((hi & 0x0F) << 8) | buf[pos + 1]
        crc = crc_hqx(view[pos + 4 : pos + PACKET_BYTES], HEADER_CRC[low12])
        if crc != (buf[pos + 2] << 8 | buf[pos + 3]) or hi & 0x80:
            self.counts.crc_errors += 1
            self._bad += 1
            self.assembler.reset()
            return None
        payload = bytes(view[pos + 4 : pos + PACKET_BYTES])
        outcome = self.assembler.push(low12, (hi >> 4) & SEGMENT_MASK, payload)
        if outcome is Outcome.BROKEN:
            self._bad += 1
            return None
        self._bad = 0
        self._realigns = 0
        self.counts.good_packets += 1
        if outcome is Outcome.NONE:
            return None
        self._since = 0
        self._silent_resyncs = 0
        self.last_segment_ns = self.source.now_ns()
        return self._frame() if outcome is Outcome.FRAME else None

    def _frame(self) -> VoSPIFrame:
        data = self.assembler.take()
        rows = np.frombuffer(data, dtype=">u2").astype(np.uint16).reshape(-1, WIDTH)
        image, telemetry_rows = tm.split(rows, location=self.telemetry_location)
        telemetry = None if telemetry_rows is None else tm.decode(telemetry_rows)
        self.frames += 1
        number = self.number + 1 if telemetry is None else telemetry.frame_counter
        self.number = number
        return VoSPIFrame(
            image=np.ascontiguousarray(image),
            number=number,
            timestamp_ns=self.source.now_ns(),
            telemetry=telemetry,
            telemetry_rows=None if telemetry_rows is None else telemetry_rows.copy(),
        )

    # -- sync ------------------------------------------------------------------------------

    def _hunt(self, end: int) -> bool:
        """Look for the packet alignment at the read position; False: need more bytes.

        Locks where a packet (discard, or video with a good CRC) is followed by one that
        agrees with it; otherwise moves on one byte. A source with a hunting limit is
        resynchronised when that many bytes passed without a lock.
        """
        buf, pos = self._buf, self._pos
        if end - pos < 2 * PACKET_BYTES:
            return False
        if self._agrees(buf, pos):
            self._hunting = False
            self._hunted = 0
            return True
        self._pos = pos + 1
        self._hunted += 1
        self.counts.bytes_skipped += 1
        if self._hunted % PACKET_BYTES == 0:
            self._since += 1
        limit = self.source.hunt_limit_bytes
        if (limit is not None and self._hunted >= limit) or self._since > LOST_AFTER_PACKETS:
            self.resync("no packet alignment")
        self._check_vospi()
        return not self._drop

    def _check_vospi(self) -> None:
        """Raise `NotVoSPIError` when a stream never showed a good packet for long."""
        c = self.counts
        if c.good_packets:
            return
        searched = c.bytes_skipped + (c.packets - c.discard) * PACKET_BYTES
        if (
            searched >= NOT_VOSPI_BYTES
            or c.reasons.get("no packet alignment", 0) >= NOT_VOSPI_RESYNCS
        ):
            raise NotVoSPIError(
                f"{self.source.path}: not a VoSPI stream: no packet with a good CRC in "
                f"{searched} bytes: check that it is the Lepton's SPI device (or a recording "
                "of one) and that the SPI mode is 3 (CPOL=1, CPHA=1)"
            )

    def _agrees(self, buf: bytearray, pos: int) -> bool:
        first = (buf[pos] << 8) | buf[pos + 1]
        second = (buf[pos + PACKET_BYTES] << 8) | buf[pos + PACKET_BYTES + 1]
        if is_discard(first):
            return is_discard(second) or crc_ok(buf, pos + PACKET_BYTES)
        if not crc_ok(buf, pos):
            return False
        if is_discard(second):
            return True
        if not crc_ok(buf, pos + PACKET_BYTES):
            return False
        number, following = first & 0x0FFF, second & 0x0FFF
        return following == number + 1 or (following == 0 and number >= PACKETS_PER_SEGMENT - 1)

    def _silence_limit(self) -> int:
        """Packets without a segment before the next resync.

        `LOST_AFTER_PACKETS`, or `STALLED_RESYNC_PACKETS` once a resync brought no segment.
        """
        return STALLED_RESYNC_PACKETS if self._silent_resyncs else LOST_AFTER_PACKETS

    def _bad_packets(self) -> None:
        """Bad packets in a row: realign in the bytes, or resync if that did not help."""
        if self._realigns >= REALIGNS_BEFORE_RESYNC:
            self.resync("bad packets after realigning")
            return
        self.counts.realigns += 1
        self.assembler.reset()
        self._bad = 0
        self._realigns += 1
        self._hunting = True
        self._hunted = 0

    def resync(self, reason: str) -> None:
        """Drop what was being assembled, deselect the device, hunt for the alignment."""
        self._check_vospi()
        self.counts.resyncs += 1
        self.counts.reasons[reason] = self.counts.reasons.get(reason, 0) + 1
        self.assembler.reset()
        self._bad = 0
        self._realigns = 0
        self._since = 0
        self._hunting = True
        self._hunted = 0
        self._drop = self.source.realigns_on_deselect
        self.source.deselect(RESYNC_IDLE_S)

    def _drop_stale(self) -> None:
        """After a deselect, drop the bytes read before it (the device realigned)."""
        self._drop = False
        self._tap(self._pos)
        self.counts.bytes_dropped += len(self._buf) - self._pos
        self._buf.clear()
        self._pos = 0
