"""The VoSPI wire format, frame assembly, telemetry and byte sources, piece by piece."""

import errno
import os

import numpy as np
import pytest

from elphel_camd.vospi import (
    FileSource,
    NotVoSPIError,
    SpidevSource,
    VoSPIError,
    VoSPIReader,
    VoSPISetupError,
    VoSPITimeoutError,
    open_source,
    sources,
)
from elphel_camd.vospi import packets as vp
from elphel_camd.vospi import telemetry as tm
from elphel_camd.vospi.frame_source import LeptonFrameSource
from elphel_camd.vospi.segments import FrameAssembler, Outcome
from elphel_sim.vospi import (
    SimSpidev,
    SimVoSPIStream,
    invalid_segment,
    segments_of,
    synthetic_frame,
    telemetry_rows,
)


def crc16_ccitt_bitwise(data: bytes) -> int:
    """x^16 + x^12 + x^5 + 1, MSB first, initial value 0, one bit at a time."""
    crc = 0
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


class MemorySource:
    """A byte source over bytes in memory, read in fixed chunks (a file without a file)."""

    realigns_on_deselect = False
    hunt_limit_bytes = None

    def __init__(self, data: bytes, chunk: int = 4000):
        self.path = "memory"
        self.data, self.chunk, self.at = data, chunk, 0
        self.deselects: list[float] = []

    def read(self, timeout_s):
        out = self.data[self.at : self.at + self.chunk]
        self.at += len(out)
        return out

    def deselect(self, seconds):
        self.deselects.append(seconds)

    def now_ns(self):
        return self.at

    def close(self):
        pass


def frame_bytes(number: int, *, telemetry: bool = False, invalid_after: bool = True) -> bytes:
    segments = segments_of(synthetic_frame(number, telemetry=telemetry))
    out = b"".join(segments)
    if invalid_after:
        out += b"".join(invalid_segment(s) for s in segments) * 2
    return vp.discard_packet() * 3 + out


def read_all(data: bytes, **kw) -> list:
    reader = VoSPIReader(MemorySource(data), **kw)
    frames = []
    with pytest.raises(EOFError):
        while True:
            frames.append(reader.read_frame(timeout_s=1e9))
    return frames


# -- wire format ----------------------------------------------------------------------------


def test_crc_is_ccitt_over_the_packet_with_the_id_top_nibble_and_crc_field_zeroed():
    payload = bytes(range(160))
    packet = vp.packet(0x1014, payload)  # packet 20 of segment 1
    expected = crc16_ccitt_bitwise(bytes((0x00, 0x14, 0, 0)) + payload)
    assert packet == bytes((0x10, 0x14)) + expected.to_bytes(2, "big") + payload
    assert vp.crc_ok(packet)
    assert vp.packet_crc(vp.packet(0x0014, payload)) == expected  # TTT is not covered
    damaged = bytearray(packet)
    damaged[100] ^= 0x01
    assert not vp.crc_ok(damaged)


def test_packet_ids_discard_number_and_segment_from_packet_20_only():
    assert vp.is_discard(0x0F00) and vp.is_discard(0xFFFF) and vp.is_discard(0x1F3A)
    assert not vp.is_discard(0x0014) and not vp.is_discard(0x3014)
    assert vp.video_id(20, 3) == 0x3014
    assert vp.video_id(19, 3) == 0x0013  # the segment number rides on packet 20 only
    assert vp.segment_number(0x3014) == 3 and vp.packet_number(0x3014) == 20
    with pytest.raises(ValueError, match=r"allowed: 0\.\.60"):
        vp.video_id(61)


# -- assembly -------------------------------------------------------------------------------


def pushes(assembler: FrameAssembler, segment: bytes) -> list[Outcome]:
    out = []
    for at in range(0, len(segment), vp.PACKET_BYTES):
        pid = (segment[at] << 8) | segment[at + 1]
        out.append(assembler.push(pid & 0x0FFF, (pid >> 12) & 7, segment[at + 4 : at + 164]))
    return out


def test_a_frame_comes_only_from_segments_1_2_3_4_in_a_row():
    s = segments_of(synthetic_frame(5, telemetry=False))
    a = FrameAssembler(packets_per_segment=60)
    for seg in (s[0], s[1], s[3]):  # segment 3 lost
        assert Outcome.FRAME not in pushes(a, seg)
    for seg in (s[0], s[1], invalid_segment(s[2]), s[3]):  # an invalid one in between
        assert Outcome.FRAME not in pushes(a, seg)
    for seg in s:
        outcomes = pushes(a, seg)
    assert outcomes[-1] is Outcome.FRAME
    image = np.frombuffer(a.take(), ">u2").reshape(120, 160)
    assert np.array_equal(image, synthetic_frame(5, telemetry=False))
    assert a.counts.frames == 1 and a.counts.frames_dropped == 2


def test_invalid_repeats_are_counted_and_dropped():
    s = segments_of(synthetic_frame(1, telemetry=False))
    a = FrameAssembler(packets_per_segment=60)
    for seg in s + [invalid_segment(x) for x in s]:
        pushes(a, seg)
    assert a.counts.frames == 1 and a.counts.segments_invalid == 4
    assert a.counts.out_of_order == 0


def test_the_packet_count_is_learnt_and_follows_telemetry_off_and_on():
    a = FrameAssembler()  # unknown: learnt from the first segment

    def frames(segments):
        return [o for seg in segments for o in pushes(a, seg)].count(Outcome.FRAME)

    with_t = segments_of(synthetic_frame(1, telemetry=True))
    without = segments_of(synthetic_frame(2, telemetry=False))
    assert frames(with_t) == 1 and a.packets_per_segment == 61
    # Off: the segment that shows it is complete with 60 packets; no frame is lost.
    assert frames(without + without) == 2 and a.packets_per_segment == 60
    # On: the first 61-packet segment was taken as 60 packets: its frame is dropped.
    assert frames(with_t + with_t) == 1 and a.packets_per_segment == 61
    assert a.counts.telemetry_switches == 2


# -- the reader -----------------------------------------------------------------------------


def test_frames_with_telemetry_carry_the_counter_and_the_decoded_rows():
    data = b"".join(frame_bytes(n, telemetry=True) for n in (7, 8, 9))
    frames = read_all(data)
    assert [f.number for f in frames] == [7, 8, 9]
    f = frames[0]
    assert f.image.shape == (120, 160) and f.image.dtype == np.uint16
    assert np.array_equal(f.image, synthetic_frame(7)[:120])
    assert f.telemetry.frame_counter == 7 and f.telemetry.fpa_temperature_centi_k == 30515
    assert f.telemetry.ffc_state == "done" and f.telemetry.tlinear
    assert f.telemetry.tlinear_resolution_k == 0.01


def test_without_telemetry_frames_are_counted_by_the_reader():
    frames = read_all(b"".join(frame_bytes(n) for n in (3, 4)))
    assert [f.number for f in frames] == [1, 2] and frames[0].telemetry is None
    assert np.array_equal(frames[1].image, synthetic_frame(4, telemetry=False))


def test_a_crc_error_drops_its_frame_only():
    first = bytearray(frame_bytes(1))
    first[vp.PACKET_BYTES * (3 + 70) + 50] ^= 0x10  # a packet of segment 2
    frames = read_all(bytes(first) + frame_bytes(2))
    assert [f.number for f in frames] == [1]  # the reader's count: frame 2 is its first
    assert np.array_equal(frames[0].image, synthetic_frame(2, telemetry=False))


def test_lost_bytes_in_a_file_are_found_again_by_the_alignment_hunt():
    data = frame_bytes(1) + frame_bytes(2)
    cut = vp.PACKET_BYTES * 100 + 37
    reader = VoSPIReader(MemorySource(data[:cut] + data[cut + 1000 :]))
    frame = reader.read_frame(timeout_s=1e9)  # frame 1 lost its bytes; frame 2 did not
    assert np.array_equal(frame.image, synthetic_frame(2, telemetry=False))
    # Realigned in the bytes: no resync (on a device, no 186 ms deselect).
    assert reader.counts.realigns >= 1 and reader.counts.resyncs == 0
    assert 0 < reader.counts.bytes_skipped < 164


def test_header_telemetry_rows_are_taken_from_the_top():
    rows = synthetic_frame(4)
    header = np.vstack([rows[120:], rows[:120]])
    data = vp.discard_packet() + b"".join(segments_of(header))
    frame = read_all(data, telemetry_location=tm.HEADER)[0]
    assert frame.number == 4 and np.array_equal(frame.image, rows[:120])


def test_telemetry_decodes_its_fields():
    rows = telemetry_rows(
        frame_counter=0x12345,
        uptime_ms=70_000,
        fpa_centi_k=30001,
        frame_mean=123,
        ffc_state=2,
        tlinear=True,
        resolution_code=0,
    )
    t = tm.decode(rows)
    assert (t.frame_counter, t.uptime_ms, t.fpa_temperature_centi_k) == (0x12345, 70_000, 30001)
    assert (t.ffc_state, t.tlinear, t.tlinear_resolution_k) == ("in_progress", True, 0.1)


def test_a_stream_that_is_not_vospi_is_named_as_such():
    noise = np.random.default_rng(1).bytes(200_000)
    reader = VoSPIReader(MemorySource(noise))
    with pytest.raises(NotVoSPIError, match=r"memory: not a VoSPI stream.*SPI mode is 3"):
        reader.read_frame(timeout_s=1e9)


# -- sources and setup ----------------------------------------------------------------------


def test_spidev_ioctl_numbers_are_linux_ones():
    assert sources.SPI_IOC_WR_MODE == 0x40016B01
    assert sources.SPI_IOC_RD_MODE == 0x80016B01
    assert sources.SPI_IOC_WR_MAX_SPEED_HZ == 0x40046B04
    assert sources.SPI_IOC_RD_MAX_SPEED_HZ == 0x80046B04


def test_spidev_setup_mode_3_clock_and_transfers_fitted_to_bufsiz():
    device = SimSpidev(SimVoSPIStream())
    source = SpidevSource(device, bufsiz=4096, clock_hz=16_000_000)
    assert device.mode() == 3 and device.max_speed_hz() == 16_000_000
    assert source.transfer_bytes == 24 * 164
    assert SpidevSource(SimSpidev(SimVoSPIStream()), bufsiz=1 << 16).transfer_bytes == 61 * 164


def test_no_device():
    with pytest.raises(VoSPIError, match=r"/dev/spidev9\.9: .*no such device.*dtparam=spi=on"):
        open_source("/dev/spidev9.9")


def test_no_permission(monkeypatch, tmp_path):
    path = tmp_path / "lepton.vospi"
    path.write_bytes(b"")

    def refuse(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(sources.os, "open", refuse)
    with pytest.raises(VoSPIError, match=f"{path}: .*permission denied.*group"):
        open_source(str(path))


def test_a_character_device_that_is_not_spidev():
    with pytest.raises(VoSPIError, match="/dev/null: not a spidev device"):
        open_source("/dev/null", bufsiz_path=sources.BUFSIZ_PARAMETER)


def test_wrong_spi_mode():
    device = SimSpidev(SimVoSPIStream(), sim_forced_mode=0)
    with pytest.raises(
        VoSPISetupError, match=r"/dev/spidev0\.0: SPI mode 0 after asking for mode 3"
    ):
        SpidevSource(device, bufsiz=4096)


def test_bufsiz_too_small_names_the_module_parameter(tmp_path):
    param = tmp_path / "bufsiz"
    param.write_text("128\n")
    assert sources.read_bufsiz(param) == 128
    assert sources.read_bufsiz(tmp_path / "absent") == 4096
    with pytest.raises(VoSPISetupError, match=r"spidev.bufsiz is 128 bytes.*bufsiz=65536"):
        SpidevSource(SimSpidev(SimVoSPIStream()), bufsiz=128)


def test_clock_outside_what_a_lepton_takes():
    with pytest.raises(VoSPISetupError, match=r"allowed: 9000000\.\.20000000"):
        SpidevSource(SimSpidev(SimVoSPIStream()), bufsiz=4096, clock_hz=24_000_000)


def test_a_wrong_mode_stream_is_not_vospi_to_the_reader():
    device = SimSpidev(SimVoSPIStream())
    source = SpidevSource(device, bufsiz=4096)
    device.sim_forced_mode = 0
    device.set_mode(0)  # the controller falls back after setup: data come a bit late
    with pytest.raises(NotVoSPIError, match="SPI mode is 3"):
        VoSPIReader(source).read_frame(timeout_s=60)


def test_a_device_that_stops_sending_times_out_naming_it():
    stream = SimVoSPIStream()
    stream.sim_stall(0.5, 1e9)
    reader = VoSPIReader(SpidevSource(SimSpidev(stream), bufsiz=4096))
    reader.read_frame(timeout_s=1)
    with pytest.raises(
        VoSPITimeoutError, match=r"/dev/spidev0\.0: no whole frame from the Lepton in 2\.\d s"
    ):
        for _ in range(20):
            reader.read_frame(timeout_s=2)
    # Deselected once (it might have lost sync); still only discard packets after that:
    # stalled, so it is read on instead of being deselected every few segment periods.
    assert reader.counts.reasons == {"no segment": 1}


def test_the_first_frame_after_a_stall_is_delivered():
    stream = SimVoSPIStream()
    stream.sim_stall(0.5, 1.0)
    reader = VoSPIReader(SpidevSource(SimSpidev(stream), bufsiz=4096))
    numbers = []
    while stream.t < 2.0:
        numbers.append(reader.read_frame(timeout_s=5).number)
    after = min(t.number for t in stream.truth.values() if t.due_s >= 1.5)
    assert after in numbers
    assert stream.truth[after].due_s < 1.5 + 12 / 106  # the next unique frame after the end


def test_a_fifo_is_read_plainly(tmp_path):
    fifo = tmp_path / "lepton.fifo"
    os.mkfifo(fifo)
    source = open_source(str(fifo))
    assert isinstance(source, FileSource) and source.fifo
    assert source.read(0.01) is None  # no writer yet: nothing, not the end
    writer = os.open(fifo, os.O_WRONLY)
    first = frame_bytes(1, invalid_after=False)  # less than the pipe's 64 KiB
    os.write(writer, first + first[3 * vp.PACKET_BYTES : 13 * vp.PACKET_BYTES])
    reader = VoSPIReader(source)
    assert np.array_equal(reader.read_frame(timeout_s=5).image, synthetic_frame(1, telemetry=False))
    os.close(writer)
    source.close()


def test_the_frame_source_refuses_a_file_that_is_not_vospi(tmp_path):
    path = tmp_path / "notes.txt"
    path.write_text("not a Lepton\n" * 1000)
    with pytest.raises(NotVoSPIError, match=r"notes\.txt: not a VoSPI stream"):
        LeptonFrameSource(str(path)).open()


def test_the_frame_source_reads_frames_and_recent_ones(tmp_path):
    path = tmp_path / "lepton.vospi"
    path.write_bytes(b"".join(frame_bytes(n, telemetry=True) for n in range(1, 6)))
    got = []
    source = LeptonFrameSource(str(path), on_frame=got.append)
    source.open()
    last = source.read_frame(after=4, timeout_s=5)
    assert last.number == 5 and source.recent(3).number == 3
    with pytest.raises(VoSPITimeoutError, match="recording has ended"):
        source.read_frame(after=5, timeout_s=5)
    assert [f.number for f in got] == [1, 2, 3, 4, 5]
    assert source.health()["state"] == "ended"
    source.close()


def test_frame_numbers_keep_rising_when_telemetry_is_turned_off():
    data = frame_bytes(500, telemetry=True) + frame_bytes(501) + frame_bytes(502)
    assert [f.number for f in read_all(data)] == [500, 501, 502]
