"""The VoSPI wire format of a FLIR Lepton 3.x: packets, their IDs and their CRC.

A packet is 164 bytes: a 16-bit ID, a 16-bit CRC, then 80 big-endian 16-bit pixels. The
ID's bits 11:0 are the packet number within a segment (restarting at 0 each segment);
bits 14:12 carry the segment number (1..4, 0 = an invalid segment) in packet 20 only; bit
15 is 0. A packet whose ID reads ``xFxx`` is a discard packet, sent until the host is in
sync and between segments. The CRC is CRC-16-CCITT (x^16 + x^12 + x^5 + 1, MSB first,
initial value 0) over the whole packet with the ID's top four bits and the CRC field set
to 0. Source: Lepton Engineering Datasheet 500-0659-00-09, the VoSPI chapter.

A segment is 60 packets (61 with telemetry), four valid segments make a frame of 160 x
120 pixels (160 x 122 with the two telemetry rows).
"""

from __future__ import annotations

from binascii import crc_hqx

PACKET_BYTES = 164
HEADER_BYTES = 4
PAYLOAD_BYTES = PACKET_BYTES - HEADER_BYTES
PIXELS_PER_PACKET = PAYLOAD_BYTES // 2
WIDTH = 160
PACKETS_PER_ROW = WIDTH // PIXELS_PER_PACKET
SEGMENTS_PER_FRAME = 4
PACKETS_PER_SEGMENT = 60
PACKETS_PER_SEGMENT_TELEMETRY = 61
SEGMENT_NUMBER_PACKET = 20  # the packet whose ID carries the segment number
DISCARD_NIBBLE = 0x0F  # low nibble of the ID's first byte on a discard packet
PACKET_NUMBER_MASK = 0x0FFF
SEGMENT_SHIFT = 12
SEGMENT_MASK = 0x7

# CRC of the four header bytes as they enter the CRC (ID top nibble and CRC field zeroed),
# by the ID's low 12 bits: the payload's CRC continues from it.
HEADER_CRC = tuple(crc_hqx(bytes((n >> 8, n & 0xFF, 0, 0)), 0) for n in range(1 << 12))


def is_discard(packet_id: int) -> bool:
    """Whether a packet ID marks a discard packet (``xFxx``)."""
    return (packet_id >> 8) & DISCARD_NIBBLE == DISCARD_NIBBLE


def packet_number(packet_id: int) -> int:
    """The packet number within its segment (ID bits 11:0)."""
    return packet_id & PACKET_NUMBER_MASK


def segment_number(packet_id: int) -> int:
    """The segment number in ID bits 14:12 (meaningful in packet 20 only; 0 = invalid)."""
    return (packet_id >> SEGMENT_SHIFT) & SEGMENT_MASK


def packet_crc(data: bytes | bytearray | memoryview, offset: int = 0) -> int:
    """The CRC a packet at ``data[offset:]`` should carry (its own CRC field ignored)."""
    low12 = ((data[offset] & 0x0F) << 8) | data[offset + 1]
    return crc_hqx(data[offset + HEADER_BYTES : offset + PACKET_BYTES], HEADER_CRC[low12])


def crc_ok(data: bytes | bytearray | memoryview, offset: int = 0) -> bool:
    """Whether the packet at ``data[offset:]`` carries the CRC of its contents."""
    sent = (data[offset + 2] << 8) | data[offset + 3]
    return packet_crc(data, offset) == sent


def packet(packet_id: int, payload: bytes) -> bytes:
    """A video packet: the ID, the CRC of ID and payload, the 160-byte payload."""
    if len(payload) != PAYLOAD_BYTES:
        raise ValueError(f"VoSPI payload of {len(payload)} bytes; allowed: {PAYLOAD_BYTES}")
    if not 0 <= packet_id <= 0x7FFF:
        raise ValueError(f"VoSPI packet ID 0x{packet_id:x}; allowed: 0..0x7fff (bit 15 is 0)")
    head = bytes((packet_id >> 8, packet_id & 0xFF, 0, 0))
    crc = crc_hqx(payload, crc_hqx(bytes((head[0] & 0x0F, head[1], 0, 0)), 0))
    return head[:2] + crc.to_bytes(2, "big") + payload


def discard_packet(fill: int = 0) -> bytes:
    """A discard packet (ID 0x0Fxx) with a constant payload."""
    return bytes((0x0F, 0xFF, 0, 0)) + bytes((fill,)) * PAYLOAD_BYTES


def video_id(number: int, segment: int = 0) -> int:
    """The ID of packet ``number`` of a segment; the segment number goes in packet 20 only."""
    if not 0 <= number < PACKETS_PER_SEGMENT_TELEMETRY:
        raise ValueError(f"VoSPI packet number {number}; allowed: 0..60")
    if not 0 <= segment <= SEGMENTS_PER_FRAME:
        raise ValueError(f"VoSPI segment number {segment}; allowed: 0..4")
    ttt = segment if number == SEGMENT_NUMBER_PACKET else 0
    return ttt << SEGMENT_SHIFT | number
