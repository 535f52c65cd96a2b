"""The stock NC393 backend's imgsrv traffic: frames decoded into elphel-camd's captures."""

import io
import json

import httpx
import numpy as np
import pytest
import tifffile

from elphel_host.camera.frames import read_tiff_metadata, read_tiff_pages
from elphel_host.camera.jp4 import decode_frame
from elphel_host.errors import CameraClientError, CameraParameterError, UnsupportedError
from elphel_sim.jp4 import encode_jp4
from tests.host.camera.stock_transcript import (
    MT9P006_STATE,
    STATE_NAMES,
    WEB,
    Transcript,
    client,
    sensor_read,
    xml,
)

T0 = 1_764_000_000_123_456_000  # a frame time, whole microseconds (Exif SubSec)
IMG = "http://cam:2323"
EXTRA = {"FP1000S": 14077, "COLOR": 5, "BITS": 8, "QUALITY": 100}


def mosaic(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(200, 3800, size=(32, 64), dtype=np.uint16)


def jp4(frame: int, **kwargs: object) -> httpx.Response:
    data = encode_jp4(
        mosaic(frame),
        bits=12,
        frame=frame,
        timestamp_ns=T0 + frame * 1000,
        exposure_us=4983,
        **kwargs,  # type: ignore[arg-type]
    )
    return httpx.Response(200, content=data, headers={"Content-Type": "image/jp4"})


def params_read(port: int = 0, frame: int = 40, **changed: int) -> tuple[str, httpx.Response]:
    url = f"{WEB}{port}&{STATE_NAMES}&SENSOR&FRAME&FP1000S&COLOR&BITS&QUALITY"
    return (url, xml({**MT9P006_STATE, **changed, "SENSOR": 0x34, "FRAME": frame, **EXTRA}))


def test_capture_decodes_the_next_frame_into_a_camd_shaped_tiff():
    steps = [(f"{IMG}/towp/wait/bimg", jp4(42)), sensor_read(), params_read(TRIG=4)]
    t = Transcript(steps)
    with client(t) as cam:
        got = cam.capture(0)
    t.done()
    meta = got.metadata
    assert list(meta)[:5] == ["frame", "timestamp_ns", "port", "sensor", "bayer"]
    assert (meta["frame"], meta["timestamp_ns"], meta["port"]) == (42, T0 + 42_000, 0)
    assert (meta["sensor"], meta["bayer"], meta["FRAME"]) == ("MT9P006", "GRBG", 42)
    assert meta["EXPOS"] == 4983 and meta["TRIG"] == 4 and meta["source"] == "jp4"
    assert meta["WOI_WIDTH"] == 64  # the frame's own window wins over the port's now
    assert got.image.dtype == np.uint16 and got.image.shape == (32, 64)
    image, stored = read_tiff_metadata(got.tiff)
    assert stored == meta and np.array_equal(image, got.image)
    # the decoder's linear data (its accuracy is tests/host/jp4's), put on the sensor's own
    # 12-bit scale: the units of a raw frame and of an elphel-camd capture
    linear = decode_frame(jp4(42).content, "image/jp4")[0].astype(np.float64)
    assert np.array_equal(got.image, np.rint(linear * 4095 / 65535).astype(np.uint16))
    assert meta["full_scale_dn"] == 4095 and got.image.max() <= 4095


def test_a_raw_tiff_frame_takes_its_bayer_from_the_sensor_and_the_flips():
    raw = mosaic(7) * 16
    buffer = io.BytesIO()
    description = json.dumps({"frame": 7, "timestamp_ns": T0, "FLIPH": 1})
    tifffile.imwrite(buffer, raw, description=description, metadata=None)
    answer = httpx.Response(200, content=buffer.getvalue(), headers={"Content-Type": "image/tiff"})
    t = Transcript([(f"{IMG}/towp/wait/bimg", answer), sensor_read(), params_read()])
    with client(t) as cam:
        got = cam.capture(0)
    t.done()
    assert got.metadata["bayer"] == "RGGB" and got.metadata["COLOR"] == 15
    assert np.array_equal(got.image, raw)


def counter(frame: int) -> tuple[str, httpx.Response]:
    return (f"{IMG}/frame", httpx.Response(200, text=f"{frame:010d}\r\n"))


def test_frame_reads_the_newest_frames_exif_only_when_the_counter_moves():
    t = Transcript([counter(42), (f"{IMG}/bimg", jp4(42)), counter(42), counter(43)])
    t.steps.append((f"{IMG}/bimg", jp4(43)))
    with client(t) as cam:
        assert cam.frame(0) == {"port": 0, "frame": 42, "timestamp_ns": T0 + 42_000}
        assert cam.frame(0)["frame"] == 42  # the same counter: no image request
        assert cam.frame(0) == {"port": 0, "frame": 43, "timestamp_ns": T0 + 43_000}
    t.done()


def test_capture_of_a_frame_number_goes_back_through_imgsrvs_buffer():
    steps = [counter(42), sensor_read(), params_read(), (f"{IMG}/last/save/bimg", jp4(42))]
    steps += [counter(42), params_read(), (f"{IMG}/last/prev/prev/save/bimg", jp4(40))]
    t = Transcript(steps)
    with client(t) as cam:
        assert cam.capture(0, frame=42).frame == 42
        assert cam.capture(0, frame=40).frame == 40
    t.done()


def test_when_the_newest_moves_on_the_capture_counts_from_the_saved_read_pointer():
    # Frames came while the path was on its way (each try was one frame late, as under
    # load): the second try steps from the place the first one saved, which stays put.
    steps = [counter(42), sensor_read(), params_read()]
    steps.append((f"{IMG}/last/prev/prev/save/bimg", jp4(41)))
    steps.append((f"{IMG}/torp/prev/save/bimg", jp4(40)))
    steps += [counter(50), params_read(), (f"{IMG}/last" + "/prev" * 5 + "/save/bimg", jp4(44))]
    steps.append((f"{IMG}/torp/next/save/bimg", jp4(45)))
    t = Transcript(steps)
    with client(t) as cam:
        assert cam.capture(0, frame=40).frame == 40
        assert cam.capture(0, frame=45).frame == 45  # the counter led imgsrv's newest
    t.done()


def test_a_frame_no_longer_in_the_buffer_is_unsupported_naming_it():
    oldest = jp4(35)  # prev stops at the oldest frame the buffer holds
    steps = [counter(42), sensor_read(), params_read()]
    steps.append((f"{IMG}/last" + "/prev" * 12 + "/save/bimg", oldest))
    steps += [(f"{IMG}/torp" + "/prev" * 5 + "/save/bimg", oldest)] * 2
    t = Transcript(steps)
    with client(t) as cam, pytest.raises(UnsupportedError, match="frame 30 is no longer in"):
        cam.capture(0, frame=30)
    t.done()


def test_capture_waits_for_a_frame_to_come_and_fetches_one_it_passed_from_the_buffer():
    steps = [counter(42), sensor_read(), params_read()]
    steps += [(f"{IMG}/towp/wait/bimg", jp4(43)), (f"{IMG}/towp/wait/bimg", jp4(44))]
    t = Transcript(steps)
    with client(t) as cam:
        assert cam.capture(0, frame=44).frame == 44
    t.done()
    steps = [counter(42), sensor_read(), params_read(), (f"{IMG}/towp/wait/bimg", jp4(45))]
    steps.append((f"{IMG}/last/prev/save/bimg", jp4(44)))  # the fetch was slower than a frame
    t = Transcript(steps)
    with client(t) as cam:
        assert cam.capture(0, frame=44).frame == 44
    t.done()
    t = Transcript([counter(42)])
    with client(t) as cam, pytest.raises(CameraParameterError, match="frame 99 is not taken"):
        cam.capture(0, frame=99)
    t.done()


def test_burst_is_consecutive_frames_in_one_multipage_tiff():
    steps = [(f"{IMG}/towp/wait/bimg", jp4(10)), sensor_read(), params_read()]
    steps += [counter(10), params_read(), (f"{IMG}/towp/wait/bimg", jp4(11))]
    steps += [counter(11), params_read(), (f"{IMG}/towp/wait/bimg", jp4(13))]
    steps.append((f"{IMG}/last/prev/save/bimg", jp4(12)))  # fell behind: from the buffer
    t = Transcript(steps)
    with client(t) as cam:
        burst = cam.burst(3, port=0)
    t.done()
    assert burst.frames == [10, 11, 12] and burst.images.shape == (3, 32, 64)
    images, metadata = read_tiff_pages(burst.tiff)
    assert metadata == burst.metadata and np.array_equal(images, burst.images)


def test_frame_answers_that_are_not_frames_are_one_line_naming_the_url():
    gif = httpx.Response(200, content=b"GIF89a", headers={"Content-Type": "image/gif"})
    truncated = jp4(5)
    truncated = httpx.Response(200, content=truncated.content[:300], headers=truncated.headers)
    for answer, match in [
        (gif, r"http://cam:2323/towp/wait/bimg: no such frame \(imgsrv sent its 1x1 GIF"),
        (httpx.Response(200, text="x"), "answered 'text/plain', not a frame; allowed: image/jp4"),
        (truncated, r"http://cam:2323/towp/wait/bimg: .*truncated"),
    ]:
        steps = [(f"{IMG}/towp/wait/bimg", answer)]
        if answer is truncated:
            steps += [sensor_read(), params_read()]
        t = Transcript(steps)
        with client(t) as cam, pytest.raises(CameraClientError, match=match) as err:
            cam.capture(0)
        assert "\n" not in str(err.value)
    t = Transcript([(f"{IMG}/frame", httpx.Response(200, text="<html>"))])
    with client(t) as cam, pytest.raises(CameraClientError, match="not a frame number"):
        cam.frame(0)
    junk = httpx.Response(200, content=b"PK\x03\x04" * 8, headers={"Content-Type": "image/jp4"})
    t = Transcript([counter(3), (f"{IMG}/bimg", junk)])
    with client(t) as cam, pytest.raises(CameraClientError) as err:
        cam.frame(0)
    assert str(err.value) == "http://cam:2323/bimg: not a JPEG: starts with 504b0304"


def test_trigger_fires_imgsrv_trig_only_in_snapshot_mode():
    gif = httpx.Response(200, content=b"GIF89a", headers={"Content-Type": "image/gif"})
    steps = [
        (f"{WEB}1&TRIG&FRAME", xml({"TRIG": 4, "FRAME": 3})),
        ("http://cam:2324/trig", gif),
        (f"{WEB}1&TRIG&FRAME", xml({"TRIG": 0, "FRAME": 3})),
    ]
    t = Transcript(steps)
    with client(t) as cam:
        cam.trigger(1)
        with pytest.raises(CameraParameterError, match="TRIG=0: one trigger needs snapshot"):
            cam.trigger(1)
    t.done()


def test_a_camera_that_does_not_answer_in_time_is_a_timeout_naming_a_readable_path():
    from elphel_host.camera.nc393.http import http_get, readable_path
    from elphel_host.errors import DeviceTimeout
    from elphel_host.limits import HostLimits

    def late(request: httpx.Request) -> httpx.Response:
        raise httpx.ReadTimeout("timed out", request=request)

    path = "/last" + "/prev" * 89 + "/save/bimg"
    imgsrv = httpx.Client(base_url=IMG, transport=httpx.MockTransport(late))
    with pytest.raises(DeviceTimeout) as info:
        http_get(imgsrv, path, limits=HostLimits.from_env(), frame=True)
    assert str(info.value).startswith(f"the camera at {IMG}/last/prev*89/save/bimg did not answer")
    assert readable_path("/torp/next/save/bimg") == "/torp/next/save/bimg"
    assert readable_path("/a/b/b/c/c/c") == "/a/b*2/c*3"
