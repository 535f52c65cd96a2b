"""Firmware transcripts: exact request bytes in, exact reply bytes out, for every command.

The firmware's StageApp and line framer run against a deterministic fake board (a
counter for a clock, recorded pins, a caliper with a fixed reading).
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

FIRMWARE = Path(__file__).resolve().parents[2] / "target" / "esp8266"
if str(FIRMWARE) not in sys.path:
    sys.path.insert(0, str(FIRMWARE))

stage_app = importlib.import_module("stage_app")
proto = importlib.import_module("stage_protocol")
config = importlib.import_module("stage_config")
caliper_read = importlib.import_module("caliper_read")


class FakePin:
    def __init__(self, level: int = 0, on_write=None) -> None:
        self.level = level
        self.on_write = on_write

    def value(self, v=None):
        if v is None:
            return self.level
        self.level = v
        if self.on_write:
            self.on_write(v)
        return None


class FakeCaliper:
    def __init__(self) -> None:
        self.last_um = None
        self.last_error = 0
        self.powered = True
        self.zero_pulses = 0
        self.fail = None

    def read(self):
        if self.fail:
            raise caliper_read.CaliperError(*self.fail)
        self.last_um = 12340
        return 12340

    def age_ms(self):
        return -1 if self.last_um is None else 0

    def pulse_zero(self):
        self.zero_pulses += 1

    def set_power(self, on):
        self.powered = bool(on)


class FakeHW:
    def __init__(self) -> None:
        self.t = 0
        self.steps = 0
        self.step = FakePin(0, self._on_step)
        self.dir = FakePin()
        self.enable = FakePin(1)
        self.lim_min = FakePin(1)
        self.lim_max = FakePin(1)
        self.caliper = FakeCaliper()
        self.serial = "TEST01"
        self.boot_id = "cafe0001"
        self.reset_cause = 0

    def _on_step(self, v):
        if v:
            self.steps += 1

    def ticks_us(self):
        return self.t

    def ticks_ms(self):
        return self.t // 1000

    def ticks_diff(self, a, b):
        return a - b

    def ticks_add(self, a, d):
        return a + d

    def sleep_us(self, us):
        self.t += us

    def ticks_ms_total(self):
        return self.t // 1000


class Session:
    def __init__(self, **cfg_over) -> None:
        self.hw = FakeHW()
        self.app = stage_app.StageApp(
            config.check(config.merge(config.DEFAULTS, cfg_over)), self.hw
        )
        self.framer = proto.LineFramer(self.app.halt)
        self.out = bytearray()

    def send(self, data: bytes) -> bytes:
        for reply in self.app.answers(self.framer, data):
            self.out.extend(reply.encode() + b"\n")
        got, self.out = bytes(self.out), bytearray()
        return got

    def run_motion(self):
        while self.app.plan is not None:
            wait = self.app.service()
            if wait > 0:
                self.hw.t += wait


def S(line: str) -> bytes:  # noqa: N802 - reads like the wire
    return (proto.seal(line) + "\n").encode()


TRANSCRIPT = [
    (b"*IDN?\n", b"ok *IDN? elphel-rig,esp8266-stage,TEST01,1.0.0\n"),
    (b"BOOT?\n", b"ok BOOT? id=cafe0001 up_ms=0 cause=0\n"),
    (
        b"STATUS?\n",
        b"ok STATUS? st=IDLE pos=0 tgt=0 homed=0 cal_um=NA cal_age_ms=-1 cal_err=0 lim=- alarm=0\n",
    ),
    (b"MOVE 10\n", b"err MOVE 9 position unknown; HOME or POS first\n"),
    (b"POS 100\n", b"ok POS 100\n"),
    (b"LIM?\n", b"ok LIM? 0 13500\n"),
    (b"MOVE 20000\n", b"err MOVE 15 target 20000 outside soft limits 0..13500\n"),
    (b"MOVE -1\n", b"err MOVE 15 target -1 outside soft limits 0..13500\n"),
    (b"ZERO\n", b"ok ZERO\n"),
    (b"LIM?\n", b"ok LIM? -100 13400\n"),
    (b"LIM 0 13000\n", b"ok LIM 0 13000\n"),
    (
        b"LIM -200 13000\n",
        b"err LIM 15 limits -200..13000 must satisfy -100 <= min < max <= 13400\n",
    ),
    (b"SPEED?\n", b"ok SPEED? 1600 8000\n"),
    (
        b"SPEED 99999 10\n",
        b"err SPEED 2 speed 99999 Hz accel 10 Hz/s; allowed 400..4000 Hz, 1..1000000 Hz/s\n",
    ),
    (b"SPEED 2000 9000\n", b"ok SPEED 2000 9000\n"),
    (b"CAL?\n", b"ok CAL? 12340 0\n"),
    (b"CALZERO\n", b"ok CALZERO\n"),
    (b"CALPWR 0\n", b"ok CALPWR 0\n"),
    (b"CALPWR 2\n", b"err CALPWR 2 CALPWR argument 2; allowed 0 or 1\n"),
    (b"CALPWR 1\n", b"ok CALPWR 1\n"),
    (b"MOVE 50\n", b"ok MOVE 50\n"),
    (b"MOVE 50\n", b"ok MOVE 50\n"),  # retry of the running move
    (b"MOVE 60\n", b"err MOVE 8 RUN in progress; STOP first\n"),
    (b"MOVER 5\n", b"err MOVER 8 RUN in progress; STOP first\n"),
    (b"CAL?\n", b"err CAL? 8 RUN in progress; STOP first\n"),
    (
        b"STATUS?\n",
        b"ok STATUS? st=RUN pos=0 tgt=50 homed=1 cal_um=12340 cal_age_ms=0 cal_err=0 lim=- alarm=0\n",  # noqa: E501 - wire bytes
    ),
    (b"!", b""),  # realtime stop: no reply
    (b"STOP\n", b"ok STOP 0\n"),
    (b"MOVER -7\n", b"err MOVER 15 target -7 outside soft limits 0..13000\n"),
    (b"MOVER 7\n", b"ok MOVER 7\n"),
    (b"FLY 1\n", b"err FLY 1 unknown command 'FLY'\n"),
    (b"MOVE\n", b"err MOVE 2 MOVE takes 1 argument(s), got 0\n"),
    (b"MOVE 1.5\n", b"err MOVE 2 MOVE argument '1.5' is not an integer of at most 9 digits\n"),
    (b"MO\xffVE 1\n", b"err ? 4 1 byte(s) outside printable ASCII\n"),
    (b"X" * 70 + b"\n", b"err ? 3 line longer than 64 bytes\n"),
    (b"STOP*00\n", b"err ? 5 checksum 00 does not match line (expected 18)\n"),
    (S("STOP"), S("ok STOP 7")),
    (S("HOME"), S("ok HOME")),
    (b"\n", b""),
]


def test_every_command_is_in_the_transcript():
    sent = set()
    for line, _ in TRANSCRIPT:
        text = line.decode("latin-1").strip()
        if len(text) > 3 and text[-3] == "*":
            text = text[:-3]
        if text and text[0] not in "!X":
            sent.add(text.split()[0].upper())
    assert set(proto.COMMANDS) <= sent | {"?"}, set(proto.COMMANDS) - sent


def test_transcript():
    s = Session()
    for i, (request, reply) in enumerate(TRANSCRIPT):
        got = s.send(request)
        assert got == reply, f"step {i}: {request!r} -> {got!r}, transcript says {reply!r}"
        if request == b"MOVER 7\n":
            s.run_motion()
    assert s.framer.buf == bytearray() and not s.out
    assert s.hw.caliper.zero_pulses == 1


def test_stop_byte_acts_before_queued_lines():
    s = Session()
    s.send(b"POS 0\nMOVE 400\n")
    for _ in range(5):
        s.app.service(budget_us=1)
        s.hw.t += 3000
    moved = s.hw.steps
    assert 0 < moved < 400
    assert s.send(b"!STATUS?\n").startswith(b"ok STATUS? st=IDLE pos=%d tgt=%d" % (moved, moved))


def test_moves_never_leave_soft_limits():
    s = Session(travel_steps=500)
    s.send(b"POS 0\n")
    assert s.send(b"MOVE 501\n").startswith(b"err MOVE 15")
    assert s.send(b"MOVE 500\n") == b"ok MOVE 500\n"
    s.run_motion()
    assert s.app.pos == 500 and s.hw.steps == 500
    assert s.send(b"MOVER 1\n").startswith(b"err MOVER 15")


def test_limit_switch_stops_with_alarm():
    s = Session()
    s.send(b"POS 0\nMOVE 300\n")
    s.app.push = lambda line: s.out.extend(line.encode() + b"\n")
    s.hw.lim_max.level = 0  # switch closes (active low)
    s.run_motion()
    assert s.app.state == "ALARM"
    assert bytes(s.out).startswith(b"# ALARM 1 max limit switch pos=")
    s.out.clear()
    assert s.send(b"MOVE 10\n") == b"err MOVE 10 alarm 1 active; HOME or POS clears it\n"


@pytest.mark.parametrize(
    ("code", "text"),
    [
        (20, "no caliper frame within 400 ms"),
        (21, "caliper frame ended after 3 of 24 bits"),
        (22, "caliper readings [1, 90] do not agree within 10 um"),
        (23, "caliper power is off (CALPWR 1 turns it on)"),
    ],
)
def test_caliper_errors_on_the_wire(code, text):
    s = Session()
    s.hw.caliper.fail = (code, text)
    assert s.send(b"CAL?\n") == f"err CAL? {code} {text}\n".encode()


def test_homing_sequence():
    s = Session(travel_steps=1000, home_backoff_steps=10)
    s.hw.lim_min.level = 1
    assert s.send(b"HOME\n") == b"ok HOME\n"
    # Run until the seek has gone 50 steps, then close the switch.
    while s.hw.steps < 50:
        w = s.app.service()
        s.hw.t += max(w, 0)
    s.hw.lim_min.level = 0
    s.app.service()
    assert s.app.home_phase == 2
    while s.hw.steps < 60:
        w = s.app.service()
        s.hw.t += max(w, 0)
    s.hw.lim_min.level = 1  # released while creeping back
    s.run_motion()
    assert s.app.state == "IDLE" and s.app.homed and s.app.pos == 0
    assert s.send(b"STATUS?\n").startswith(b"ok STATUS? st=IDLE pos=0 tgt=0 homed=1")
