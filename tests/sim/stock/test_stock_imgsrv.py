"""imgsrv of the simulated stock NC393: command sequences, frames, formats, bad requests."""

import io
import re
from datetime import UTC, datetime

import numpy as np
import tifffile
from PIL import Image

from elphel_host.camera.exif import read_exif
from elphel_sim.stock.imgsrv import GIF_1X1


def exif_of(data: bytes) -> dict[int, object]:
    exif = Image.open(io.BytesIO(data)).getexif()
    return {**dict(exif), **dict(exif.get_ifd(0x8769))}


def frame_of(client) -> int:
    r = client.get("/frame")
    assert re.fullmatch(rb"\d{10}\r\n", r.content), r.content
    return int(r.content)


def set_params(web, query: str, firmware, port: int = 0) -> None:
    web.get(f"/parsedit.php?immediate&sensor_port={port}&{query}")
    assert firmware.wait_frame(port, firmware.frame(port) + 4)


def snapshot(web, firmware) -> None:
    """Port 0 to snapshot mode with no trigger, once its ring buffer is full: frames stop."""
    assert firmware.wait_frame(0, 70)
    web.get("/parsedit.php?immediate&TRIG=4")
    while True:
        frame = firmware.frame(0)
        if not firmware.wait_frame(0, frame + 1, timeout_s=0.3):
            return


def test_towp_wait_bimg_is_the_next_frame_as_jp4(imgsrv, firmware):
    before = frame_of(imgsrv[0])
    r = imgsrv[0].get("/towp/wait/bimg")
    assert r.status_code == 200
    assert r.headers["content-type"] == "image/jp4"
    assert r.headers["access-control-allow-origin"] == "*"
    exif = exif_of(r.content)
    assert exif[0x9211] > before  # ImageNumber: a frame taken after the request
    assert exif[0x0129] == (0, 4)  # PageNumber: the sensor port
    words = exif[0x927C]
    assert len(words) == 16
    assert (words[10] >> 4) & 0xF == 5  # COLOR_MODE JP4
    assert words[8] == 256 << 16 and words[9] == 128 << 16  # WOI width / height
    assert words[4] == 0x0A390400 and words[13] & 0x7F == 100  # Elphel's gamma; quality
    ns = int(firmware.board.sim_frame_truth(0, exif[0x9211])["timestamp_ns"])
    when = datetime.fromtimestamp(ns // 10**9, tz=UTC).strftime("%Y:%m:%d %H:%M:%S")
    assert exif[0x9003] == when and exif[0x9291] == f"{(ns // 1000) % 10**6:06d}"
    sec, usec = ns // 10**9, (ns // 1000) % 10**6
    assert r.headers["content-disposition"] == (
        f'inline; filename="elphelimg_{sec}_{usec:06d}_0.jp4"'
    )


def test_bimg_is_the_newest_frame_and_names_by_timestamp(imgsrv, firmware):
    newest = firmware.frame(0)
    r = imgsrv[0].get("/timestamp_name/bchn4/sbimg")
    assert r.headers["content-type"] == "image/jp4", r.headers
    assert exif_of(r.content)[0x9211] >= newest
    assert re.fullmatch(
        r'attachment; filename="\d+_\d{6}_4\.jp4"', r.headers["content-disposition"]
    )
    assert r.headers["expires"] == "0" and r.headers["pragma"] == "no-cache"


def test_pointer_moves(web, imgsrv, firmware):
    snapshot(web, firmware)  # no trigger: the buffer stands still
    newest, oldest = firmware.frame(0), firmware.oldest(0)
    assert newest - oldest == 63  # the ring holds 64 frames

    def number(path: str) -> int:
        return exif_of(imgsrv[0].get(path).content)[0x9211]

    assert number("/img") == number("/last/bimg") == newest
    assert number("/prev/prev/img") == newest - 2
    assert number("/first/bimg") == number("/first/prev/bimg") == oldest
    assert number("/second/next/save/bimg") == oldest + 2
    assert number("/torp/bimg") == oldest + 2  # the saved global read pointer
    assert number("/towp/prev/bimg") == newest
    for path in ("/towp/bimg", "/next/bimg", "/last/next/next/img"):  # not taken yet
        assert imgsrv[0].get(path).content == GIF_1X1, path


def test_frame_and_wframe(imgsrv):
    a = frame_of(imgsrv[0])
    r = imgsrv[0].get("/wframe")
    assert r.headers["content-type"].startswith("text/plain")
    assert int(r.content) > a
    assert frame_of(imgsrv[3]) == 0  # no sensor on port 3


def test_color_15_is_a_16_bit_tiff_of_the_read_out_frame(web, imgsrv, firmware):
    set_params(web, "COLOR=15", firmware)
    r = imgsrv[0].get("/towp/wait/bimg")
    assert r.headers["content-type"] == "image/tiff"
    assert r.headers["content-disposition"].endswith('.tiff"')
    with tifffile.TiffFile(io.BytesIO(r.content)) as tif:
        page = tif.pages[0]
        image = page.asarray()
        frame = page.tags[0x9211].value
        assert page.tags[0x0129].value == (0, 4)
        exif = page.tags["ExifTag"].value  # the Exif IFD, as a JPEG frame's
        assert exif["DateTimeOriginal"].startswith("1970:01:01")
    assert len(read_exif(r.content).maker_note) == 16
    assert image.dtype == np.uint16 and image.shape == (128, 256)
    assert np.array_equal(image, firmware.board.capture(0, frame=frame).image)


def test_color_2_is_jp46(web, imgsrv, firmware):
    set_params(web, "COLOR=2&QUALITY=90", firmware)
    r = imgsrv[0].get("/towp/wait/bimg")
    assert r.headers["content-type"] == "image/jp46"
    words = exif_of(r.content)[0x927C]
    assert (words[10] >> 4) & 0xF == 2 and words[13] & 0x7F == 90


def test_lepton_frames_are_always_tiff(imgsrv):
    r = imgsrv[2].get("/towp/wait/bimg")
    assert r.headers["content-type"] == "image/tiff"
    with tifffile.TiffFile(io.BytesIO(r.content)) as tif:
        assert tif.pages[0].shape[1] == 160


def test_trig_takes_one_frame_in_snapshot_mode(web, imgsrv, firmware):
    snapshot(web, firmware)
    stopped = firmware.frame(0)
    assert not firmware.wait_frame(0, stopped + 1, timeout_s=0.5)  # no trigger, no frame
    imgsrv[0].get("/trig")
    assert firmware.wait_frame(0, stopped + 1, timeout_s=5)
    assert not firmware.wait_frame(0, stopped + 2, timeout_s=0.5)  # one trigger, one frame
    imgsrv[0].get("/trig")
    assert firmware.wait_frame(0, stopped + 2, timeout_s=5)


def test_bad_requests(imgsrv):
    for path in ("/nosuchcommand", "/towp/bimg", "/prev", "/pointers"):
        r = imgsrv[0].get(path)
        assert (r.headers["content-type"], r.content) == ("image/gif", GIF_1X1), path
    assert imgsrv[3].get("/bimg").content == GIF_1X1  # a port without a sensor
    r = imgsrv[0].get("/")
    assert r.headers["content-type"].startswith("text/plain") and b"towp" in r.content
