"""A fake elphel-camd that lies: every answer ends in one line and exit 1, within bounds."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.host.hostile.crafted import claiming_tiff, frame_metadata, frame_tiff, nested_json
from tests.host.hostile.fakes import (
    FakeDevice,
    Responder,
    assert_one_line_failure,
    chunk,
    drip,
    endless,
    head,
    json_answer,
    run_elphel,
    whole,
)

INFO = {
    "board": "sim",
    "daemon": "elphel-camd",
    "version": "0.1",
    "capabilities": [],
    "ports": [{"port": 0, "sensor": {"model": "MT9P006", "bits": 12, "bayer": "GRBG"}}],
}
# Short bounds, so every case ends in seconds.
# Slack beyond a deadline for the work after it (the error, the exit) on a loaded machine.
SLACK_S = 2.0
FAST = {"ELPHEL_LIMIT_DEADLINE_S": "3", "ELPHEL_LIMIT_JSON_BYTES": "1000000"}


@pytest.fixture
def device() -> Iterator[list[FakeDevice]]:
    made: list[FakeDevice] = []
    yield made
    for d in made:
        d.close()


def serve(made: list[FakeDevice], respond: Responder) -> str:
    fake = FakeDevice(respond)
    made.append(fake)
    return fake.url


def always(answer: bytes) -> Responder:
    def respond(method: str, path: str, body: bytes, conn: socket.socket) -> None:
        conn.sendall(answer)

    return respond


@pytest.mark.parametrize(
    ("answer", "needle"),
    [
        (json_answer({}), "board"),
        (json_answer([]), "the answer"),
        (json_answer(None), "the answer"),
        (json_answer({**INFO, "ports": "0,1"}), "ports"),
        (json_answer({**INFO, "ports": [{"port": "0", "sensor": None}]}), "ports.0.port"),
        (whole(nested_json(100_000).encode()), "nested"),
        (whole(b'{"board": NaN}'), "NaN"),
    ],
)
def test_malformed_info_is_one_line(device: list[FakeDevice], answer: bytes, needle: str) -> None:
    url = serve(device, always(answer))
    run = run_elphel(["camera", "info", "--camera", url], **FAST)
    assert_one_line_failure(run, url, needle)


def test_endless_json_is_cut_at_its_limit(device: list[FakeDevice]) -> None:
    url = serve(device, lambda m, p, b, conn: endless(conn, b'{"a": 1} '))
    run = run_elphel(["camera", "info", "--camera", url], **FAST)
    assert_one_line_failure(run, url, "exceeds 1000000 bytes", "ELPHEL_LIMIT_JSON_BYTES")


def test_a_claimed_length_over_the_limit_is_refused_at_once(device: list[FakeDevice]) -> None:
    answer = head(content_length=str(300 << 20)) + b"{" * 1000
    url = serve(device, always(answer))
    run = run_elphel(["camera", "info", "--camera", url], **FAST)
    assert_one_line_failure(run, "claims 314572800 bytes", "json_bytes")


def test_a_dripping_answer_ends_at_the_deadline(device: list[FakeDevice]) -> None:
    url = serve(device, lambda m, p, b, conn: drip(conn, every_s=0.5))
    run = run_elphel(["camera", "info", "--camera", url], **FAST)
    assert_one_line_failure(run, url, "GET /info", "no complete answer within 3 s")
    # Without the deadline the drip goes on for ever.
    assert run.seconds < 3 + SLACK_S, run.seconds


def test_error_details_are_escaped_and_cut(device: list[FakeDevice]) -> None:
    detail = "\x1b]0;pwned\x07\x1b[2J" + "<html>" + "x" * 5000
    url = serve(device, always(json_answer({"detail": detail}, status=500)))
    run = run_elphel(["camera", "info", "--camera", url], **FAST)
    assert_one_line_failure(run, "HTTP 500", "\\x1b]0;pwned\\x07", "more chars")


def test_a_patch_reply_without_frame(device: list[FakeDevice]) -> None:
    def respond(method: str, path: str, body: bytes, conn: socket.socket) -> None:
        if method == "PATCH":
            conn.sendall(json_answer({"params": {"EXPOS": 5000}}))
        else:
            conn.sendall(json_answer({"EXPOS": 100, "FRAME": 3}))

    url = serve(device, respond)
    run = run_elphel(["camera", "set", "EXPOS=5000", "--camera", url], **FAST)
    assert_one_line_failure(run, "PATCH", "frame", "Field required")


@pytest.mark.parametrize(
    ("metadata", "needle"),
    [
        ('{"frame": Infinity, "port": 0}', "Infinity"),
        (frame_metadata(frame=None), "frame"),
        ('{"port": 0}', "frame"),
        ('{"frame": ' + nested_json(100_000) + "}", "nested"),
        ('{"frame": 1e999}', "overflows"),
    ],
)
def test_bad_capture_metadata_writes_nothing(
    device: list[FakeDevice], tmp_path: Path, metadata: str, needle: str
) -> None:
    url = serve(device, always(whole(frame_tiff(metadata), content_type="image/tiff")))
    out = tmp_path / "f.tif"
    run = run_elphel(["camera", "capture", "--camera", url, "--out", str(out)], **FAST)
    assert_one_line_failure(run, needle)
    assert list(tmp_path.iterdir()) == []


def test_a_deflate_bomb_is_refused_before_decoding(
    device: list[FakeDevice], tmp_path: Path
) -> None:
    tiff = claiming_tiff(24000, 24000, frame_metadata())
    url = serve(device, always(whole(tiff, content_type="image/tiff")))
    out, png = tmp_path / "f.tif", tmp_path / "f.png"
    run = run_elphel(
        ["camera", "capture", "--camera", url, "--out", str(out), "--png", str(png)], **FAST
    )
    assert_one_line_failure(run, "24000x24000", "frame_pixels")
    assert list(tmp_path.iterdir()) == []


def test_an_endless_frame_is_cut_at_the_frame_limit(device: list[FakeDevice]) -> None:
    url = serve(device, lambda m, p, b, conn: endless(conn, b"II*\0", content_type="image/tiff"))
    env = {**FAST, "ELPHEL_LIMIT_FRAME_PIXELS": "1000000", "ELPHEL_LIMIT_DEADLINE_S": "20"}
    run = run_elphel(["camera", "capture", "--camera", url], **env)
    assert_one_line_failure(run, "exceeds 3000000 bytes", "frame_pixels")


def test_a_failed_preview_leaves_no_tiff(device: list[FakeDevice], tmp_path: Path) -> None:
    tiff = frame_tiff(frame_metadata(bayer="XYZW"))
    url = serve(device, always(whole(tiff, content_type="image/tiff")))
    out, png = tmp_path / "f.tif", tmp_path / "f.png"
    run = run_elphel(
        ["camera", "capture", "--camera", url, "--out", str(out), "--png", str(png)], **FAST
    )
    assert_one_line_failure(run, "XYZW")
    assert list(tmp_path.iterdir()) == []


def test_a_good_capture_writes_both(device: list[FakeDevice], tmp_path: Path) -> None:
    tiff = frame_tiff(frame_metadata())
    url = serve(device, always(whole(tiff, content_type="image/tiff")))
    out, png = tmp_path / "f.tif", tmp_path / "f.png"
    run = run_elphel(
        ["camera", "capture", "--camera", url, "--out", str(out), "--png", str(png)], **FAST
    )
    assert run.code == 0, run.stderr
    assert out.read_bytes() == tiff
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.png", "f.tif"]


def events(*pieces: bytes) -> Responder:
    def respond(method: str, path: str, body: bytes, conn: socket.socket) -> None:
        if path.startswith("/api/v1/info"):
            conn.sendall(json_answer(INFO))
            return
        conn.sendall(head(content_type="text/event-stream", transfer_encoding="chunked"))
        for piece in pieces:
            conn.sendall(chunk(piece))
        if pieces and pieces[-1].endswith(b"..."):
            while True:
                conn.sendall(chunk(b"x" * 65536))
        time.sleep(30)

    return respond


@pytest.mark.parametrize(
    ("pieces", "env", "needle"),
    [
        ((b"data: ...",), {}, "a line longer than 65536 bytes"),
        (((b"data: " + b"1" * 100 + b"\n") * 20_000,), {}, "an event longer than 1048576 bytes"),
        ((b'event: frame\ndata: {"frame": 3, "timestamp_ns": 1}\n\n',), {}, "port"),
        ((b": hello\n\n",), {"ELPHEL_LIMIT_KEEPALIVE_S": "0.5"}, "silent for 1.5 s"),
    ],
)
def test_hostile_event_streams(
    device: list[FakeDevice], pieces: tuple[bytes, ...], env: dict[str, str], needle: str
) -> None:
    url = serve(device, events(*pieces))
    run = run_elphel(["camera", "watch", "--camera", url, "--count", "5"], **FAST, **env)
    assert_one_line_failure(run, needle)
    assert run.seconds < 2 + SLACK_S, run.seconds
