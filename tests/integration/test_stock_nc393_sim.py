"""End to end: `elphel-sim up --firmware elphel` serves a simulated stock NC393."""

import io
import re
import signal
import time
from urllib.parse import urlsplit

import httpx
import numpy as np
import pytest
import tifffile
from PIL import Image

from .rig import start_rig, stop_rig


@pytest.fixture(scope="module")
def nc393():
    """The mixed scenario as a stock NC393; yields (announcement, web URL, imgsrv URLs)."""
    proc, announce = start_rig("--firmware", "elphel", "--scenario", "mixed", "--seed", "2")
    url = urlsplit(announce["camera_url"])
    base = int(re.fullmatch(r"imgsrv=(\d+)", url.query).group(1))
    imgsrv = [f"http://{url.hostname}:{base + p}" for p in range(4)]
    try:
        yield proc, announce, f"http://{url.hostname}:{url.port}", imgsrv
    finally:
        stderr = stop_rig(proc)
        assert proc.returncode == 0, f"elphel-sim up exited {proc.returncode}: {stderr}"


def xml_values(text: str) -> dict[str, int]:
    return {k: int(v) for k, v in re.findall(r"<(\w+)>(-?\d+)</\1>", text)}


def test_announcement_is_a_stock_camera_url(nc393):
    _, announce, _, _ = nc393
    assert re.fullmatch(r"nc393://127\.0\.0\.1:\d+\?imgsrv=\d+", announce["camera_url"])
    assert announce["token"] is None
    assert announce["sim_url"].startswith("http://127.0.0.1:")
    assert {"stage_url", "stage_pty"} <= announce.keys()


def test_parsedit_answers_sensors_and_writes_ahead(nc393):
    _, _, web, _ = nc393
    codes = [
        xml_values(httpx.get(f"{web}/parsedit.php?immediate&sensor_port={p}&SENSOR").text)
        for p in range(4)
    ]
    assert [c["SENSOR"] for c in codes] == [0x34, 0x38, 0x44, 0]
    r = httpx.get(f"{web}/parsedit.php?immediate&FRAME&WOI_WIDTH=512*3&WOI_HEIGHT=256*3")
    assert r.headers["access-control-allow-origin"] == "*"
    frame = xml_values(r.text)["FRAME"]
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        now = xml_values(httpx.get(f"{web}/parsedit.php?immediate&FRAME&WOI_WIDTH").text)
        if now["FRAME"] > frame + 3:
            break
        time.sleep(0.1)
    assert now["WOI_WIDTH"] == 512
    r = httpx.get(f"{web}/parsedit.php?immediate&NOSUCHNAME")
    assert r.status_code == 200 and "misspelled constant: 'NOSUCHNAME'" in r.text


def test_imgsrv_serves_the_next_frame_as_jp4_and_raw_tiff(nc393):
    imgsrv = nc393[3]
    before = int(httpx.get(f"{imgsrv[0]}/frame").content)
    r = httpx.get(f"{imgsrv[0]}/towp/wait/bimg", timeout=60)
    assert r.headers["content-type"] == "image/jp4"
    exif = Image.open(io.BytesIO(r.content)).getexif()
    assert exif[0x9211] > before
    assert len(exif.get_ifd(0x8769)[0x927C]) == 16
    r = httpx.get(f"{imgsrv[2]}/towp/wait/bimg", timeout=60)  # the Lepton
    assert r.headers["content-type"] == "image/tiff"
    image = tifffile.imread(io.BytesIO(r.content))
    assert image.dtype == np.uint16 and image.shape[1] == 160
    assert httpx.get(f"{imgsrv[3]}/bimg").headers["content-type"] == "image/gif"


def test_sigterm_stops_it_cleanly(nc393):
    proc, _, web, _ = nc393
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=20) == 0
    with pytest.raises(httpx.ConnectError):
        httpx.get(f"{web}/parsedit.php?immediate&FRAME", timeout=2)


def test_a_start_says_nothing_of_the_sensors_that_are_not_there():
    """The mixed scenario leaves addresses empty on every port but 0: probing finds them
    empty, which is no failure and no line on stderr."""
    proc, _ = start_rig("--firmware", "elphel", "--scenario", "mixed", "--seed", "2")
    stderr = stop_rig(proc)
    assert proc.returncode == 0, stderr
    assert "no device at" not in stderr and "attempt" not in stderr, stderr
