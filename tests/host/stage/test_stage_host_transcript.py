"""Host client transcripts: the exact bytes each call sends and the reply it parses.

A scripted port stands in for the serial link; every expected write must happen, in
order, and every scripted reply must be consumed.
"""

from __future__ import annotations

import dataclasses

import pytest

from elphel_host.errors import (
    StageCaliperError,
    StageLimitError,
    StageProtocolError,
    StageResetError,
)
from elphel_host.stage import StageClient

BOOT = (b"BOOT?*29\n", b"ok BOOT? id=cafe0001 up_ms=5000 cause=0*0D\n")
IDLE_500 = b"ok STATUS? st=IDLE pos=500 tgt=500 homed=1 cal_um=4390 cal_age_ms=120 cal_err=0 lim=- alarm=0*25\n"  # noqa: E501 - wire bytes


class ScriptedPort:
    def __init__(self, script: list[tuple[bytes, bytes]]) -> None:
        self.script = list(script)
        self.pending = bytearray()
        self.closed = False

    def write(self, data: bytes) -> int:
        assert self.script, f"unexpected write {data!r}: script exhausted"
        want, reply = self.script.pop(0)
        assert data == want, f"sent {data!r}, transcript expects {want!r}"
        self.pending.extend(reply)
        return len(data)

    def flush(self) -> None:
        pass

    @property
    def in_waiting(self) -> int:
        return len(self.pending)

    def read(self, n: int = 1) -> bytes:
        data = bytes(self.pending[:n])
        del self.pending[:n]
        return data

    def close(self) -> None:
        self.closed = True

    def assert_done(self) -> None:
        assert not self.script, f"transcript not consumed: {self.script!r}"
        assert not self.pending, f"reply bytes not consumed: {bytes(self.pending)!r}"


def client_for(script: list[tuple[bytes, bytes]]) -> tuple[StageClient, ScriptedPort]:
    port = ScriptedPort([BOOT, *script])
    client = StageClient("scripted://", opener=lambda url: port)  # type: ignore[arg-type,return-value]
    return client, port


CASES = [
    (
        "identify",
        (),
        [(b"*IDN?*56\n", b"ok *IDN? elphel-rig,esp8266-stage,sim00000,1.0.0*64\n")],
        ("elphel-rig", "esp8266-stage", "sim00000", "1.0.0"),
    ),
    ("limits_steps", (), [(b"LIM?*77\n", b"ok LIM? 0 13500*54\n")], (0, 13500)),
    ("set_limits_steps", (0, 13000), [(b"LIM 0 13000*4A\n", b"ok LIM 0 13000*6E\n")], None),
    ("speed", (), [(b"SPEED?*78\n", b"ok SPEED? 1600 8000*53\n")], (1600, 8000)),
    ("set_speed", (2000, 9000), [(b"SPEED 2000 9000*4C\n", b"ok SPEED 2000 9000*68\n")], None),
    ("read_caliper_um", (), [(b"CAL?*71\n", b"ok CAL? 4390 3*68\n")], 4390),
    ("zero", (), [(b"ZERO*02\n", b"ok ZERO*26\n")], None),
    ("zero_caliper", (), [(b"CALZERO*4C\n", b"ok CALZERO*68\n")], None),
    ("caliper_power", (False,), [(b"CALPWR 0*0B\n", b"ok CALPWR 0*2F\n")], None),
    ("declare_position_steps", (500,), [(b"POS 500*59\n", b"ok POS 500*7D\n")], None),
    ("stop", (), [(b"!", b""), (b"STOP*18\n", b"ok STOP 512*2A\n")], 512),
]


@pytest.mark.parametrize(("method", "args", "script", "expected"), CASES, ids=[c[0] for c in CASES])
def test_command_transcript(method, args, script, expected):
    client, port = client_for(script)
    result = getattr(client, method)(*args)
    if dataclasses.is_dataclass(result):
        result = dataclasses.astuple(result)
    if expected is not None:
        assert result == expected
    port.assert_done()
    client.close()
    assert port.closed


def test_status_transcript():
    client, port = client_for([(b"STATUS?*2B\n", IDLE_500)])
    st = client.status()
    assert (st.state, st.steps, st.target_steps, st.homed) == ("IDLE", 500, 500, True)
    assert (st.caliper_um, st.caliper_age_ms, st.caliper_error, st.limits, st.alarm) == (
        4390,
        120,
        0,
        "-",
        0,
    )
    port.assert_done()


def test_move_handle_transcript():
    run = b"ok STATUS? st=RUN pos=550 tgt=600 homed=1 cal_um=4390 cal_age_ms=400 cal_err=0 lim=- alarm=0*69\n"  # noqa: E501 - wire bytes
    idle = b"ok STATUS? st=IDLE pos=600 tgt=600 homed=1 cal_um=4390 cal_age_ms=500 cal_err=0 lim=- alarm=0*23\n"  # noqa: E501 - wire bytes
    client, port = client_for(
        [(b"MOVE 600*07\n", b"ok MOVE 600*23\n"), (b"STATUS?*2B\n", run), (b"STATUS?*2B\n", idle)]
    )
    seen = []
    handle = client.move_to_steps(600)
    handle.add_callback(lambda h: seen.append(h.final.steps))
    final = handle.wait(timeout=5)
    assert final.steps == 600 and handle.done and seen == [600]
    port.assert_done()


def test_home_transcript():
    idle = b"ok STATUS? st=IDLE pos=0 tgt=0 homed=1 cal_um=830 cal_age_ms=10 cal_err=0 lim=- alarm=0*22\n"  # noqa: E501 - wire bytes
    client, port = client_for([(b"HOME*0F\n", b"ok HOME*2B\n"), (b"STATUS?*2B\n", idle)])
    assert client.home().wait(timeout=5).homed
    port.assert_done()


def test_error_reply_maps_to_exception():
    client, port = client_for(
        [(b"MOVE 99999*08\n", b"err MOVE 15 target 99999 outside soft limits 0..13500*22\n")]
    )
    with pytest.raises(StageLimitError, match=r"99999 outside soft limits 0\.\.13500") as e:
        client.move_to_steps(99999)
    assert e.value.code == 15 and isinstance(e.value, ValueError)
    port.assert_done()


def test_caliper_error_reply():
    client, port = client_for([(b"CAL?*71\n", b"err CAL? 21 caliper frame rejected: glitch*23\n")])
    with pytest.raises(StageCaliperError, match="error 21"):
        client.read_caliper_um()
    port.assert_done()


def test_damaged_reply_is_retried_not_believed():
    garbled = IDLE_500.replace(b"pos=500", b"pos=5\xb00")
    client, port = client_for([(b"STATUS?*2B\n", garbled), (b"STATUS?*2B\n", IDLE_500)])
    assert client.status().steps == 500
    port.assert_done()


def test_damaged_request_is_retried():
    client, port = client_for(
        [
            (b"CAL?*71\n", b"err ? 5 checksum 71 does not match line (expected 70)\n"),
            (b"CAL?*71\n", b"ok CAL? 4390 3*68\n"),
        ]
    )
    assert client.read_caliper_um() == 4390
    port.assert_done()


def test_persistent_garbage_raises_protocol_error():
    client, port = client_for([(b"LIM?*77\n", b"ok LIM? 0 13500*00\n")] * 5)
    with pytest.raises(StageProtocolError, match="after 5 attempt"):
        client.limits_steps()
    port.assert_done()


def test_banner_with_new_boot_id_is_a_reset():
    banner = b"# ELPHEL-STAGE 1.0.0 boot=0badf00d serial=sim00000\n"
    client, port = client_for([(b"STATUS?*2B\n", banner + IDLE_500)])
    with pytest.raises(StageResetError, match="cafe0001 -> 0badf00d"):
        client.status()
    assert client.resets_seen == 1
    port.pending.clear()
    port.assert_done()
