"""The HTTP server's bounds hold with either of uvicorn's HTTP/1.1 parsers.

The daemon serves with httptools (C, a dependency) and falls back to h11 (pure Python)
where httptools is missing; the request deadline, the head size limit, keep-alive and the
event stream's cut work the same with both.
"""

import contextlib
import socket
import time

import httpx
import pytest

from elphel_camd import serving
from elphel_camd.events import EventHub
from elphel_camd.service import CameraService
from elphel_sim.board import SimCameraBoard
from elphel_sim.scenarios import build

from .served import TOKEN, serve


@pytest.fixture(params=["httptools", "h11"])
def parser(request, monkeypatch):
    if request.param == "h11":
        monkeypatch.setattr(serving, "_httptools_protocol", lambda: None)
    else:
        assert serving._httptools_protocol() is not None, "httptools is a dependency"
    return request.param


@pytest.fixture
def service():
    board = SimCameraBoard(build("default", seed=4), seed=4)
    cam = CameraService(board, events=EventHub(16, replay=64, max_subscribers=4))
    yield cam
    cam.close()


def port_of(url: str) -> int:
    return int(url.rsplit(":", 1)[1])


def read_all(sock: socket.socket, timeout_s: float = 5.0) -> bytes:
    """Everything the server sends until it closes the connection."""
    sock.settimeout(timeout_s)
    chunks = []
    with contextlib.suppress(ConnectionResetError):
        while chunk := sock.recv(65536):
            chunks.append(chunk)
    return b"".join(chunks)


def test_the_parser_in_use_is_the_one_asked_for(parser):
    assert serving.http_stack(serving.server_config(object())) in (
        f"{parser}, uvloop",
        f"{parser}, asyncio",
    )


def test_half_open_and_slow_requests_are_dropped(parser, service):
    with serve(service, request_timeout_s=1.0, idle_timeout_s=1.0) as srv:
        silent = socket.create_connection(("127.0.0.1", port_of(srv.url)))
        slow = socket.create_connection(("127.0.0.1", port_of(srv.url)))
        slow.sendall(b"GET /api/v1/info HTTP/1.1\r\nHost: camera\r\n")  # never finished
        start = time.monotonic()
        for s in (silent, slow):
            assert read_all(s) == b""
            s.close()
        assert time.monotonic() - start < 3
        assert httpx.get(srv.url + "/api/v1/info", timeout=5).status_code == 200


def test_a_head_over_the_limit_is_answered_400_and_closed(parser, service):
    with serve(service, max_head_bytes=4096) as srv:
        big = socket.create_connection(("127.0.0.1", port_of(srv.url)))
        pad = b"".join(b"X-Pad-%02d: " % i + b"a" * 52 + b"\r\n" for i in range(100))
        # 100 x 64 bytes of headers: past 4 KiB before the head ends.
        big.sendall(b"GET /api/v1/info HTTP/1.1\r\nHost: camera\r\n" + pad)
        answer = read_all(big)
        big.close()
        assert answer.startswith(b"HTTP/1.1 400")
        # A head within the limit, padded to just under it, is served.
        small = {"X-Pad": "a" * 3500}
        assert httpx.get(srv.url + "/api/v1/info", headers=small, timeout=5).status_code == 200


def test_keep_alive_and_pipelined_requests_are_each_answered(parser, service):
    with serve(service) as srv:
        sock = socket.create_connection(("127.0.0.1", port_of(srv.url)))
        one = b"GET /api/v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
        last = b"GET /api/v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n"
        sock.sendall(one * 4 + last)
        answer = read_all(sock)
        sock.close()
        assert answer.count(b"HTTP/1.1 200") == 5
        # Requests on one connection, each after its answer: the head count starts over.
        with httpx.Client(base_url=srv.url, timeout=5) as client:
            for _ in range(50):
                r = client.get("/api/v1/info", headers={"X-Pad": "a" * 2000})
                assert r.status_code == 200


def _patch_bytes(body_bytes: int, *, token: bool = False) -> bytes:
    """A PATCH of EXPOS whose JSON body is padded with spaces to ``body_bytes``."""
    body = b'{"EXPOS": 1000}'
    body += b" " * (body_bytes - len(body))
    auth = f"Authorization: Bearer {TOKEN}\r\n".encode() if token else b""
    return (
        b"PATCH /api/v1/ports/0/params HTTP/1.1\r\nHost: 127.0.0.1\r\n"
        b"Content-Type: application/json\r\nConnection: close\r\n"
        + auth
        + b"Content-Length: %d\r\n\r\n" % len(body)
        + body
    )


@pytest.mark.parametrize("body_bytes", [17, 4097, 20000, 65536])
def test_a_body_sent_with_its_head_does_not_count_as_head(parser, service, body_bytes):
    with serve(service, max_head_bytes=4096) as srv:
        sock = socket.create_connection(("127.0.0.1", port_of(srv.url)))
        sock.sendall(_patch_bytes(body_bytes, token=True))  # one write: head and body together
        answer = read_all(sock)
        sock.close()
        assert answer.startswith(b"HTTP/1.1 200"), answer[:200]


def test_a_body_over_the_limit_is_413_whatever_the_reads(parser, service):
    with serve(service) as srv:
        sock = socket.create_connection(("127.0.0.1", port_of(srv.url)))
        with contextlib.suppress(ConnectionError):
            sock.sendall(_patch_bytes(65537, token=True))
        answer = read_all(sock)
        sock.close()
        assert answer.startswith(b"HTTP/1.1 413"), answer[:200]
        assert b'"limit":"max_body_bytes"' in answer.replace(b" ", b"")


def _head_lines(answer: bytes) -> list[tuple[str, str]]:
    """The header lines of a raw HTTP answer, names in lower case."""
    head = answer.split(b"\r\n\r\n", 1)[0].decode("latin-1").split("\r\n")[1:]
    return [(n.strip().lower(), v.strip()) for n, v in (line.split(":", 1) for line in head)]


def _assert_safe_headers_once(answer: bytes) -> None:
    lines = _head_lines(answer)
    for name, value in (("x-content-type-options", "nosniff"), ("referrer-policy", "no-referrer")):
        assert [v for n, v in lines if n == name] == [value], (name, answer[:400])


def _raw(url: str, request: bytes) -> bytes:
    sock = socket.create_connection(("127.0.0.1", port_of(url)))
    with contextlib.suppress(ConnectionError):
        sock.sendall(request)
    answer = read_all(sock)
    sock.close()
    return answer


@pytest.mark.parametrize(
    "request_bytes",
    [
        b"NOT HTTP AT ALL\r\n\r\n",
        b"GET /api/v1/info HTTP/1.1\r\nHost camera\r\n\r\n",  # a header line without a colon
        b"GET /api/v1/info HTTP/1.1\r\nHost: camera\r\nX-Pad: " + b"a" * 5000,  # never ends
    ],
    ids=["request-line", "header-line", "head-too-large"],
)
def test_the_servers_own_400_carries_the_safe_headers(parser, service, request_bytes):
    with serve(service, max_head_bytes=4096) as srv:
        answer = _raw(srv.url, request_bytes)
    assert answer.startswith(b"HTTP/1.1 400"), answer[:200]
    _assert_safe_headers_once(answer)


def test_the_servers_503_over_the_connection_limit_carries_the_safe_headers(parser, service):
    # One connection at most: the one that asks is already at the limit.
    with serve(service, max_connections=1) as srv:
        answer = _raw(srv.url, b"GET /api/v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
    assert answer.startswith(b"HTTP/1.1 503"), answer[:200]
    _assert_safe_headers_once(answer)


@pytest.mark.parametrize("path", ["/api/v1/health", "/", "/nowhere"])
def test_the_apps_answers_carry_each_safe_header_once(parser, service, path):
    request = f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n".encode()
    with serve(service) as srv:
        answer = _raw(srv.url, request)
    assert answer.split(b" ", 2)[1] in (b"200", b"404"), answer[:200]
    _assert_safe_headers_once(answer)
