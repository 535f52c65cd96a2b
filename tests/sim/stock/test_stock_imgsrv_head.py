"""imgsrv sends a frame's Exif head first and forms its image only for a client that reads on.

The host learns the newest frame's number and time from the first bytes of ``/bimg``
and hangs up; the simulator must not form a full image for that. A frame asked for by
several requests, at once or one after the other, is formed and encoded once.
"""

import contextlib
import io
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor

import httpx
import pytest
import uvicorn
from fastapi import FastAPI
from PIL import Image

from elphel_host.camera.nc393.frames import newest_stamp
from elphel_host.limits import HostLimits
from elphel_sim.launcher import bind_loopback
from elphel_sim.stock.firmware import StockFirmware
from elphel_sim.stock.server import PIXELS_AFTER_S, imgsrv_app

from .test_stock_imgsrv import exif_of, set_params, snapshot


@pytest.fixture
def served(firmware: StockFirmware) -> Iterator[str]:
    """Port 0's imgsrv on a loopback socket (a real HTTP server: clients can hang up)."""
    with serving(imgsrv_app(firmware, 0)) as url:
        yield url


@contextlib.contextmanager
def serving(app: FastAPI) -> Iterator[str]:
    """``app`` served on a loopback socket from a thread; its URL."""
    sock = bind_loopback(0)
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", lifespan="off"))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    host, port = sock.getsockname()[:2]
    try:
        yield f"http://{host}:{port}"
    finally:
        server.should_exit = True
        thread.join(timeout=10)
        sock.close()


@pytest.fixture
def captures(firmware: StockFirmware, monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The frames the firmware's service formed an image of, one entry per forming."""
    formed: list[int] = []
    capture = firmware.service.capture

    def counted(port: int, *, frame: int | None = None):
        got = capture(port, frame=frame)
        formed.append(got[0].frame)
        return got

    monkeypatch.setattr(firmware.service, "capture", counted)
    return formed


def test_a_newest_frame_poll_forms_no_image(web, served, firmware, captures):
    snapshot(web, firmware)  # no trigger: the newest frame stays the newest
    newest = firmware.frame(0)
    with httpx.Client(base_url=served, timeout=30) as client:

        def unexpected(data: bytes, kind: str, url: str):
            raise AssertionError(f"{url} sent a {kind} frame whole")

        for _ in range(3):
            frame, stamp = newest_stamp(client, unexpected, limits=HostLimits())
            assert frame == newest
        truth = int(firmware.board.sim_frame_truth(0, newest)["timestamp_ns"])
        assert stamp == truth // 1000 * 1000  # Exif times are whole microseconds
        time.sleep(3 * PIXELS_AFTER_S)  # past the time a reader would get pixels
        assert captures == []
        assert firmware.kept(0, newest) is None
        whole = client.get("/bimg")
    head, _ = firmware.head(0, newest)
    assert whole.content.startswith(head.data) and len(whole.content) > len(head.data)
    assert exif_of(whole.content)[0x9211] == newest
    assert "content-length" not in whole.headers  # sent head first, then the rest
    assert captures == [newest]


def test_a_frame_asked_for_at_once_and_again_is_formed_once(web, served, firmware, captures):
    snapshot(web, firmware)
    newest = firmware.frame(0)
    with ThreadPoolExecutor(3) as pool:
        answers = list(pool.map(lambda _: httpx.get(f"{served}/bimg", timeout=30), range(3)))
    again = httpx.get(f"{served}/last/prev/next/bimg", timeout=30)
    assert {a.content for a in answers} == {again.content}
    assert again.headers["content-length"] == str(len(again.content))  # kept: sent whole
    assert captures == [newest]


def test_a_frame_whose_head_was_sent_comes_whole_after_leaving_the_ring(
    firmware, captures, monkeypatch
):
    held: list[tuple[str, int]] = []
    for name in ("hold", "release"):
        real = getattr(firmware, name)
        monkeypatch.setattr(
            firmware, name, lambda p, f, real=real, name=name: (held.append((name, f)), real(p, f))
        )
    # 40 frames/s: the ring's 64 frames turn over in 1.6 s, before the rest is formed
    with serving(imgsrv_app(firmware, 0, pixels_after_s=2.5)) as url:
        answer = httpx.get(f"{url}/bimg", timeout=30)
    number = exif_of(answer.content)[0x9211]
    assert number < firmware.oldest(0)  # gone from the ring meanwhile
    assert Image.open(io.BytesIO(answer.content)).size == (256, 128)  # the whole frame
    assert captures == [number]
    assert held == [("hold", number), ("release", number)]  # held from its head until sent


@pytest.mark.parametrize(
    "query",
    [
        "COLOR=5&WOI_WIDTH=250&WOI_HEIGHT=130&FLIPH=1",
        "COLOR=2&QUALITY=80&WOI_WIDTH=200&WOI_HEIGHT=100&FLIPV=1&GTAB_R=0x00640400",
    ],
)
def test_the_head_is_the_start_of_the_encoded_file(web, firmware, query):
    set_params(web, query, firmware)
    frame = firmware.frame(0)
    got = firmware.head(0, frame)
    assert got is not None
    head, metadata = got
    encoded, full = firmware.encoded(0, frame)
    assert encoded.data.startswith(head.data)
    assert (head.content_type, head.extension) == (encoded.content_type, encoded.extension)
    assert metadata["timestamp_ns"] == full["timestamp_ns"]


def test_a_raw_frame_has_no_head_of_its_own(web, firmware):
    set_params(web, "COLOR=15", firmware)
    assert firmware.head(0, firmware.frame(0)) is None
