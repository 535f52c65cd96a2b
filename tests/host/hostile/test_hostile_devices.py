"""A fake stock NC393 (parsedit.php, imgsrv) and a fake stage on loopback, both lying."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator

import httpx
import pytest

from elphel_host.camera.frames import CapturedFrame
from elphel_host.camera.nc393.frames import newest_stamp
from elphel_host.camera.nc393.http import http_get
from elphel_host.errors import DeviceLimitError
from elphel_host.limits import HostLimits
from elphel_host.stage.protocol import seal
from tests.host.hostile.fakes import (
    FakeDevice,
    assert_one_line_failure,
    endless,
    head,
    run_elphel,
)

LIMITS = HostLimits(json_bytes=1 << 20, frame_pixels=1 << 20, deadline_s=5.0)


@pytest.fixture
def made() -> Iterator[list[FakeDevice]]:
    devices: list[FakeDevice] = []
    yield devices
    for d in devices:
        d.close()


def test_an_endless_parsedit_answer(made: list[FakeDevice]) -> None:
    fake = FakeDevice(lambda m, p, b, conn: endless(conn, b"<x>1</x>", content_type="text/xml"))
    made.append(fake)
    url = f"nc393://127.0.0.1:{fake.port}"
    run = run_elphel(["camera", "info", "--camera", url], ELPHEL_LIMIT_JSON_BYTES="1000000")
    assert_one_line_failure(run, "parsedit.php", "exceeds 1000000 bytes")


def test_a_parsedit_answer_claiming_300_mb(made: list[FakeDevice]) -> None:
    def respond(method: str, path: str, body: bytes, conn: socket.socket) -> None:
        conn.sendall(head(content_type="text/xml", content_length=str(300 << 20)) + b"<p>")
        time.sleep(5)

    fake = FakeDevice(respond)
    made.append(fake)
    run = run_elphel(["camera", "info", "--camera", f"nc393://127.0.0.1:{fake.port}"])
    assert_one_line_failure(run, "claims 314572800 bytes", "json_bytes")


def test_endless_app0_segments_before_the_exif(made: list[FakeDevice]) -> None:
    def respond(method: str, path: str, body: bytes, conn: socket.socket) -> None:
        conn.sendall(head(content_type="image/jp4", transfer_encoding="chunked"))
        conn.sendall(b"2\r\n\xff\xd8\r\n")
        segment = b"\xff\xe0\x00\x10" + bytes(14)
        block = segment * 3000
        while True:
            conn.sendall(f"{len(block):x}\r\n".encode() + block + b"\r\n")

    fake = FakeDevice(respond)
    made.append(fake)

    def raw(data: bytes, kind: str, url: str) -> CapturedFrame:
        raise AssertionError("a JPEG is not decoded whole")

    with httpx.Client(base_url=fake.url) as client, pytest.raises(DeviceLimitError) as e:
        newest_stamp(client, raw, limits=LIMITS)
    assert "no Exif block in the first 262144 bytes" in str(e.value)


def test_an_endless_imgsrv_frame(made: list[FakeDevice]) -> None:
    fake = FakeDevice(lambda m, p, b, conn: endless(conn, b"\xff", content_type="image/jp4"))
    made.append(fake)
    start = time.monotonic()
    with httpx.Client(base_url=fake.url) as client, pytest.raises(DeviceLimitError) as e:
        http_get(client, "/bimg", limits=LIMITS, frame=True)
    assert f"exceeds {LIMITS.frame_bytes + LIMITS.json_bytes} bytes" in str(e.value)
    assert time.monotonic() - start < LIMITS.deadline_s


def stage(reply_to_boot: bytes) -> FakeDevice:
    """A stage board answering every line with ``reply_to_boot``."""

    def respond(conn: socket.socket) -> None:
        while conn.recv(4096):
            conn.sendall(reply_to_boot)

    return FakeDevice(respond, raw=True)


@pytest.mark.parametrize(
    ("reply", "needle"),
    [
        ((seal("ok BOOT? up_ms=5000 cause=0") + "\n").encode(), "BOOT? answered"),
        (b"\x1b]0;pwned\x07" * 20_000, "a line longer than 4096 bytes"),
    ],
)
def test_a_stage_that_lies(made: list[FakeDevice], reply: bytes, needle: str) -> None:
    fake = stage(reply)
    made.append(fake)
    run = run_elphel(["stage", "status", "--stage", f"socket://127.0.0.1:{fake.port}"])
    assert_one_line_failure(run, needle)
