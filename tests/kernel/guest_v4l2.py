"""The v4l2 image path against a real kernel: run inside the guest that test_kernel_tier boots.

Not collected on the host (its name does not start with ``test_``): the tier's runner
passes it to pytest inside a virtme-ng guest where vivid and i2c-stub are loaded, the
nodes are real and every ioctl reaches Debian's kernel.
"""

from __future__ import annotations

import glob
import os
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from smbus2 import SMBus

from elphel_camd.boards.v4l2 import V4L2Board
from elphel_camd.errors import DeviceBusyError, PortDisconnectedError, VideoNodeError
from elphel_camd.frame_metadata import bayer_after_flips
from elphel_camd.i2c.bus import open_bus
from elphel_camd.params import EXPOSURE, WINDOW
from elphel_camd.sensors import MT9P006, detect
from elphel_camd.sensors.mt9p006_registers import CHIP_ID, I2C_ADDRESS
from elphel_camd.service import CameraService
from elphel_camd.v4l2 import media
from elphel_camd.v4l2.formats import raw_format
from elphel_camd.v4l2.node import VideoNode
from elphel_host.camera.frames import read_tiff_pages
from tests.camd.served import AUTH, serve

NODE = "/dev/video0"
SIZE = "640x480"
# vivid's "100% Colorbar" pattern: eight bars of (R, G, B) fully on or off, left to right.
BARS = [(1, 1, 1), (1, 1, 0), (0, 1, 1), (0, 1, 0), (1, 0, 1), (1, 0, 0), (0, 0, 1), (0, 0, 0)]
CHANNEL = {"R": 0, "G": 1, "B": 2}


def ctl(**controls: int) -> None:
    """Set vivid's controls through v4l2-ctl (another process, as a user would)."""
    settings = ",".join(f"{k}={v}" for k, v in controls.items())
    subprocess.run(["v4l2-ctl", "-d", NODE, "-c", settings], check=True)


@pytest.fixture(autouse=True)
def colour_bars() -> Iterator[None]:
    ctl(test_pattern=1, osd_text_mode=2, percentage_of_dropped_buffers=0, horizontal_flip=0)
    yield


def expected_bars(
    shape: tuple[int, int], bayer: str, bits: int, *, mirrored: bool = False
) -> np.ndarray:
    """The colour bars (right to left if mirrored) as a sensor with order ``bayer`` reads them."""
    width = shape[1]
    image = np.zeros(shape, np.uint16)
    full = (1 << bits) - 1
    columns = np.arange(width)
    bar_of_column = (width - 1 - columns if mirrored else columns) * len(BARS) // width
    for dy in (0, 1):
        for dx in (0, 1):
            channel = CHANNEL[bayer[2 * dy + dx]]
            on = np.array([bar[channel] for bar in BARS])[bar_of_column[dx::2]]
            image[dy::2, dx::2] = on * full
    return image


def board(fourcc: str, **kwargs: Any) -> V4L2Board:
    return V4L2Board(ports=[{"video": NODE, "format": fourcc, "size": SIZE}], **kwargs)


@pytest.mark.parametrize("fourcc", ["RG10", "BA10", "GB12", "BG12", "RG16", "GR16"])
def test_bayer_frames_match_vivids_bars_pixel_for_pixel(fourcc: str) -> None:
    b = board(fourcc)
    try:
        got = b.capture(0, timeout_s=30)
        sensor = b.sensors()[0]
        label = bayer_after_flips(sensor.bayer, 0, 0)
        assert label == raw_format(fourcc).bayer
        np.testing.assert_array_equal(
            got.image, expected_bars(got.image.shape, label, raw_format(fourcc).bits)
        )
    finally:
        b.close()


MONO = ("GREY", "Y10 ", "Y12 ", "Y16 ")


def v4l2_ctl_frame(fourcc: str, directory: Path) -> np.ndarray:
    """One frame of ``fourcc`` taken by v4l2-ctl (another reader), decoded here."""
    raw_file = directory / "frame.raw"
    width, height = (int(v) for v in SIZE.split("x"))
    subprocess.run(
        [
            "v4l2-ctl",
            "-d",
            NODE,
            f"--set-fmt-video=width={width},height={height},pixelformat={fourcc}",
            "--stream-mmap",
            "--stream-count=1",
            f"--stream-to={raw_file}",
        ],
        check=True,
        capture_output=True,
    )
    data = raw_file.read_bytes()
    stride = len(data) // height  # a line's bytes, padding included
    dtype = np.uint8 if raw_format(fourcc).bits == 8 else np.dtype("<u2")
    lines = np.frombuffer(data, dtype).reshape(height, -1)
    assert lines.shape[1] * lines.itemsize == stride
    return lines[:, :width].astype(np.uint16)


def assert_luma_bars(image: np.ndarray) -> None:
    """Eight uniform vertical bars, from white down to black in luma."""
    bar_width = image.shape[1] // len(BARS)
    levels = []
    for k in range(len(BARS)):
        bar = image[:, k * bar_width : (k + 1) * bar_width]
        assert (bar == bar[0, 0]).all(), f"bar {k} is not uniform: {np.unique(bar)[:8]}"
        levels.append(int(bar[0, 0]))
    assert levels == sorted(levels, reverse=True) and len(set(levels)) == len(BARS), levels


def test_mono_frames_through_the_daemon_have_no_bayer_label_and_match_vivid(
    tmp_path: Path,
) -> None:
    probe = VideoNode(NODE, size=(640, 480))
    offered = [f for f in MONO if f in probe.offered()]
    probe.close()
    assert offered, f"vivid offers none of {MONO}"
    for fourcc in offered:
        reference = v4l2_ctl_frame(fourcc, tmp_path)
        assert_luma_bars(reference)
        service = CameraService(board(fourcc))
        try:
            with serve(service) as served, httpx.Client(base_url=served.url, headers=AUTH) as c:
                r = c.post("/api/v1/ports/0/capture", timeout=60)
                assert r.status_code == 200, r.text
                images, (meta,) = read_tiff_pages(r.content)
                schema = c.get("/api/v1/ports/0/params/schema").json()
        finally:
            service.close()
        assert meta["bayer"] is None and schema["bayer"] is None, (fourcc, meta["bayer"])
        assert service.sensor(0).bits == raw_format(fourcc).bits
        np.testing.assert_array_equal(images[0], reference, err_msg=fourcc)


def test_a_flip_mirrors_the_bars_and_the_label_is_the_nodes_order() -> None:
    b = board("RG10")
    try:
        sensor = b.sensors()[0]
        assert {"FLIPH", "FLIPV", "GAINR"} <= sensor.writable and "EXPOS" not in sensor.writable
        state = sensor.defaults()
        state["FLIPH"] = 1
        sensor.program(WINDOW, state)
        first = b.capture(0, timeout_s=30).frame
        got = b.capture(0, frame=first + 2, timeout_s=30)  # a frame started after the flip
        label = bayer_after_flips(sensor.bayer, 1, 0)
        fmt = b.streams[0].source.refresh_format()
        assert label == fmt.format.bayer
        expected = expected_bars(got.image.shape, label, 10, mirrored=True)
        # vivid draws mirrored bars with their edges a pixel pair off; compare the columns
        # two pixels or more from an edge (95% of the frame), every one exactly.
        bar_width = got.image.shape[1] // len(BARS)
        columns = np.arange(got.image.shape[1]) % bar_width
        inside = (columns >= 2) & (columns < bar_width - 2)
        np.testing.assert_array_equal(got.image[:, inside], expected[:, inside])
        assert sensor.actual_gains({"FRAME": got.frame})["FLIPH"] == 1
    finally:
        b.close()


def patch_window(c: httpx.Client, **woi: int) -> tuple[int, np.ndarray, np.ndarray, dict]:
    """PATCH a window; the frame it names, that frame, the frame before and its metadata."""
    assert c.post("/api/v1/ports/0/capture", timeout=60).status_code == 200
    r = c.patch("/api/v1/ports/0/params", json=woi, timeout=60)
    assert r.status_code == 200, r.text
    first = r.json()["frame"]
    got = c.post("/api/v1/ports/0/capture", params={"frame": first}, timeout=60)
    before = c.post("/api/v1/ports/0/capture", params={"frame": first - 1}, timeout=60)
    assert got.status_code == 200 and before.status_code == 200, (got.text, before.text)
    (new,), (meta,) = read_tiff_pages(got.content)
    (old,), _ = read_tiff_pages(before.content)
    return first, new, old, meta


def test_a_window_on_the_webcam_input_switches_mode_at_the_frame_the_patch_names() -> None:
    b = board("RG10")
    service = CameraService(b)
    try:
        with serve(service) as served, httpx.Client(base_url=served.url, headers=AUTH) as c:
            schema = c.get("/api/v1/ports/0/params/schema").json()
            writable = {n for n, spec in schema["params"].items() if spec["writable"]}
            assert {"WOI_WIDTH", "WOI_HEIGHT"} <= writable and "WOI_LEFT" not in writable
            sizes = b.streams[0].source.shape_options().sizes
            width, height = min(sizes, key=lambda size: size[0] * size[1])
            _, new, old, meta = patch_window(c, WOI_WIDTH=width, WOI_HEIGHT=height)
            refused = c.patch("/api/v1/ports/0/params", json={"WOI_WIDTH": width + 2})
    finally:
        service.close()
    assert (640, 480) in sizes and (width, height) != (640, 480)
    assert old.shape == (480, 640) and new.shape == (height, width)
    assert (meta["WOI_WIDTH"], meta["WOI_HEIGHT"]) == (width, height)
    np.testing.assert_array_equal(new, expected_bars(new.shape, "RGGB", 10))
    assert refused.status_code == 422, refused.text
    assert f"{width}x{height}, " in refused.json()["allowed"]


@pytest.fixture
def hdmi_input() -> Iterator[None]:
    """vivid's second input, HDMI, which crops (ccs_cap_mode=1); back to the webcam after."""
    subprocess.run(["v4l2-ctl", "-d", NODE, "-i", "1"], check=True)
    subprocess.run(["v4l2-ctl", "-d", NODE, "--set-dv-bt-timings", "index=0"], check=False)
    try:
        yield
    finally:
        subprocess.run(["v4l2-ctl", "-d", NODE, "-i", "0"], check=True)


def dropped(c: httpx.Client) -> int:
    return int(c.get("/api/v1/health").json()["ports"][0]["stream"]["dropped"])


def capture_page(c: httpx.Client, **params: int) -> tuple[np.ndarray, dict[str, Any]]:
    r = c.post("/api/v1/ports/0/capture", params=params, timeout=60)
    assert r.status_code == 200, r.text
    (image,), (meta,) = read_tiff_pages(r.content)
    return image, meta


def test_a_window_through_vivids_crop_starts_at_the_frame_the_patch_names(
    hdmi_input: None,
) -> None:
    """vivid's HDMI input runs at 60 fps and the emulated guest loses frames: the frame the
    PATCH names, and the one before, are checked when they were not lost themselves."""
    b = V4L2Board(ports=[{"video": NODE, "format": "RG10"}], buffers=8, ring_frames=16)
    service = CameraService(b)
    try:
        with serve(service) as served, httpx.Client(base_url=served.url, headers=AUTH) as c:
            schema = c.get("/api/v1/ports/0/params/schema").json()
            width, height = schema["window"]["width"], schema["window"]["height"]
            left, top = width // 8 * 2, height // 8 * 2
            woi = {
                "WOI_LEFT": left,
                "WOI_TOP": top,
                "WOI_WIDTH": width // 2,
                "WOI_HEIGHT": height // 2,
            }
            old, before = capture_page(c)
            lost = dropped(c)
            r = c.patch("/api/v1/ports/0/params", json=woi, timeout=60)
            assert r.status_code == 200, r.text
            first = r.json()["frame"]
            named = c.post("/api/v1/ports/0/capture", params={"frame": first}, timeout=60)
            previous = c.post("/api/v1/ports/0/capture", params={"frame": first - 1}, timeout=60)
            some_lost = dropped(c) > lost
            pages = [capture_page(c) for _ in range(6)]
            refused = c.patch("/api/v1/ports/0/params", json={"WOI_LEFT": width})
    finally:
        service.close()
    assert old.shape == (height, width) and before["WOI_WIDTH"] == width
    for image, meta in pages:  # each frame's metadata is its own shape
        assert image.shape == (meta["WOI_HEIGHT"], meta["WOI_WIDTH"]), meta
    for answer, shape in ((named, (height // 2, width // 2)), (previous, (height, width))):
        if answer.status_code == 404 and some_lost:  # that frame itself was lost
            continue
        assert answer.status_code == 200, answer.text
        (image,), _ = read_tiff_pages(answer.content)
        assert image.shape == shape
    new, meta = pages[-1]
    assert new.shape == (height // 2, width // 2)
    assert {k: meta[k] for k in woi} == woi and meta["bayer"] == "RGGB"
    full = expected_bars((height, width), "RGGB", 10)
    expected = full[top : top + height // 2, left : left + width // 2]
    # Compare the columns two pixels or more from a bar's edge (as the mirrored bars).
    bar_width = width // len(BARS)
    columns = (np.arange(width // 2) + left) % bar_width
    inside = (columns >= 2) & (columns < bar_width - 2)
    np.testing.assert_array_equal(new[:, inside], expected[:, inside])
    assert refused.status_code == 422 and "crop bounds" in refused.json()["allowed"]


def test_frame_numbers_follow_the_sequence_with_monotonic_timestamps() -> None:
    b = board("RG10")
    try:
        frames = [b.capture(0, timeout_s=30) for _ in range(4)]
        numbers = [f.frame for f in frames]
        assert numbers == list(range(numbers[0], numbers[0] + 4))
        stamps = [f.timestamp_ns for f in frames]
        assert stamps == sorted(stamps) and len(set(stamps)) == 4
        assert abs(stamps[-1] / 1e9 - time.monotonic()) < 5  # CLOCK_MONOTONIC
        assert b.port_status(0)["dropped"] == 0
    finally:
        b.close()


def test_dropped_buffers_are_counted_and_reported() -> None:
    b = board("RG10")
    events: list[tuple[str, dict[str, Any]]] = []
    b.on_event(lambda kind, payload: events.append((kind, payload)))
    try:
        b.capture(0, timeout_s=30)
        ctl(percentage_of_dropped_buffers=50)
        deadline = time.monotonic() + 60
        while b.port_status(0)["dropped"] < 2 and time.monotonic() < deadline:
            time.sleep(0.1)
        ctl(percentage_of_dropped_buffers=0)
        status = b.port_status(0)  # no more drops: frames and drops are final up to here
        assert status["dropped"] >= 2, status
        # frames are numbered from 1 by the sequence: the numbers skip the dropped frames
        assert b.streams[0].last_frame >= status["frames"] + status["dropped"], status
        assert [p for k, p in events if p.get("error") == "frames_dropped"]
    finally:
        b.close()


def test_a_disconnect_is_reported_refused_and_recovered_from() -> None:
    b = board("RG10")
    events: list[tuple[str, dict[str, Any]]] = []
    b.on_event(lambda kind, payload: events.append((kind, payload)))
    held = os.open(NODE, os.O_RDWR)  # vivid stays disconnected while any handle is open
    try:
        before = b.capture(0, timeout_s=30).frame
        ctl(disconnect=1)
        deadline = time.monotonic() + 30
        while b.port_status(0)["state"] != "disconnected" and time.monotonic() < deadline:
            time.sleep(0.05)
        assert "disconnected" in [p["state"] for k, p in events if k == "port"], events
        with pytest.raises(PortDisconnectedError, match="is disconnected"):
            b.capture(0, timeout_s=5)
        os.close(held)
        held = -1
        while b.port_status(0)["state"] != "streaming" and time.monotonic() < deadline + 30:
            time.sleep(0.1)
        assert b.port_status(0)["state"] == "streaming", b.port_status(0)
        assert b.capture(0, timeout_s=30).frame > before
    finally:
        if held >= 0:
            os.close(held)
        b.close()


def test_a_fatal_streaming_error_restarts_the_stream() -> None:
    b = board("RG10")
    events: list[tuple[str, dict[str, Any]]] = []
    b.on_event(lambda kind, payload: events.append((kind, payload)))
    try:
        before = b.capture(0, timeout_s=30).frame
        ctl(inject_fatal_streaming_error=1)
        deadline = time.monotonic() + 60
        while b.port_status(0)["restarts"] < 1 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert b.port_status(0)["restarts"] >= 1, (b.port_status(0), events)
        assert b.capture(0, timeout_s=30).frame > before
    finally:
        b.close()


def test_a_node_streamed_by_another_program_is_busy() -> None:
    b = board("RG10")
    try:
        other = VideoNode(NODE, fourcc="RG10", size=(640, 480))
        try:
            with pytest.raises(DeviceBusyError, match="another program is streaming"):
                other.start(2)
        finally:
            other.close()
    finally:
        b.close()


def test_a_stream_the_driver_refuses_to_start_names_media_ctl_and_the_overlay() -> None:
    ctl(inject_vidioc_streamon_error=1)  # the next STREAMON fails
    with pytest.raises(
        VideoNodeError, match=r"starting the stream failed.*media-ctl.*media-controller=0"
    ):
        board("RG10")
    b = board("RG10")  # the node is usable again afterwards
    try:
        assert b.capture(0, timeout_s=30).frame >= 1
    finally:
        b.close()


def test_vivids_media_graph_is_read_and_no_sensor_feeds_its_node() -> None:
    medias = sorted(glob.glob("/dev/media*"))
    assert medias, "no /dev/media*: vivid registers one when the kernel has MEDIA_CONTROLLER"
    video = media.device_number(NODE)
    fd = os.open(medias[0], os.O_RDWR)
    try:
        topology, driver = media.read_topology(fd), media.read_driver(fd)
    finally:
        os.close(fd)
    entity = topology.entity_of(media.INTF_T_V4L_VIDEO, video)
    assert driver == "vivid" and entity is not None, (driver, topology)
    assert topology.entities[entity][1] == 0x00010001  # MEDIA_ENT_F_IO_V4L: a video node
    assert topology.sensor_of(video) is None  # vivid has no sensor subdevice
    assert media.open_sensor(NODE) is None  # so the board streams from the node alone


def test_no_such_node_names_the_nodes_present() -> None:
    with pytest.raises(
        VideoNodeError, match=r"/dev/video9: no such V4L2 node; nodes present: .*/dev/video0"
    ):
        VideoNode("/dev/video9")


def _stub_bus() -> str:
    for name_file in glob.glob("/sys/class/i2c-dev/i2c-*/name"):
        if Path(name_file).read_text().strip() == "SMBus stub driver":
            return "/dev/" + Path(name_file).parent.name
    raise AssertionError("i2c-stub is not loaded (modprobe i2c-stub chip_addr=0x48)")


def test_the_mt9p006_is_driven_through_i2c_stub_with_smbus_words() -> None:
    path = _stub_bus()
    with SMBus(path) as raw:  # the chip id, high byte first on the sensor's wire
        raw.write_word_data(I2C_ADDRESS, 0x00, ((CHIP_ID & 0xFF) << 8) | (CHIP_ID >> 8))
    bus = open_bus(path)
    assert getattr(bus, "mode", None) == "smbus-word"
    driver = detect(bus, bus_name=path)
    assert isinstance(driver, MT9P006)
    driver.init()
    state = driver.defaults()
    state["VEXPOS"] = 1234
    state = driver.normalize(state, frozenset({"VEXPOS"}))
    driver.program(EXPOSURE, state)
    shutter = driver.table["shutter_width_lower"].address
    with SMBus(path) as raw:
        word = raw.read_word_data(I2C_ADDRESS, shutter)
    assert ((word & 0xFF) << 8 | word >> 8) == 1234 & 0xFFFF
    assert driver.read("shutter_width_lower") == 1234


def test_through_the_daemon_frames_match_the_bars_and_numbers_follow_the_sequence() -> None:
    service = CameraService(board("BA10"))
    try:
        with serve(service) as served, httpx.Client(base_url=served.url, headers=AUTH) as c:
            metas = []
            for _ in range(3):
                r = c.post("/api/v1/ports/0/capture", timeout=60)
                assert r.status_code == 200, r.text
                images, (meta,) = read_tiff_pages(r.content)
                metas.append(meta)
            assert meta["bayer"] == "GRBG" and int(r.headers["X-Frame-Number"]) == meta["frame"]
            np.testing.assert_array_equal(images[0], expected_bars(images[0].shape, "GRBG", 10))
            frames = [m["frame"] for m in metas]
            assert frames == sorted(frames) and len(set(frames)) == 3
            status = c.get("/api/v1/health").json()["ports"][0]["stream"]
            assert status["frames"] >= frames[-1] - frames[0] + 1 and status["dropped"] == 0
    finally:
        service.close()


def test_through_the_daemon_a_disconnect_is_503_and_the_health_says_so() -> None:
    service = CameraService(board("RG10"))
    held = os.open(NODE, os.O_RDWR)
    try:
        with serve(service) as served, httpx.Client(base_url=served.url, headers=AUTH) as c:
            assert c.post("/api/v1/ports/0/capture", timeout=60).status_code == 200
            ctl(disconnect=1)
            deadline = time.monotonic() + 30
            while c.get("/api/v1/health").status_code == 200 and time.monotonic() < deadline:
                time.sleep(0.1)
            health = c.get("/api/v1/health")
            assert health.status_code == 503
            assert health.json()["ports"][0]["error"] == "disconnected"
            r = c.post("/api/v1/ports/0/capture", timeout=60)
            assert r.status_code == 503 and r.json()["error"] == "disconnected"
            os.close(held)
            held = -1
            while c.get("/api/v1/health").status_code != 200 and time.monotonic() < deadline + 30:
                time.sleep(0.2)
            assert c.post("/api/v1/ports/0/capture", timeout=60).status_code == 200
    finally:
        if held >= 0:
            os.close(held)
        service.close()


def test_a_node_paired_with_an_i2c_bus_gets_its_sensor_from_the_projects_driver() -> None:
    path = _stub_bus()
    with SMBus(path) as raw:
        raw.write_word_data(I2C_ADDRESS, 0x00, ((CHIP_ID & 0xFF) << 8) | (CHIP_ID >> 8))
    service = CameraService(
        V4L2Board(ports=[{"video": NODE, "format": "RG10", "size": SIZE, "bus": path}])
    )
    try:
        assert isinstance(service.sensor(0), MT9P006)
        target = service.set_params(0, {"VEXPOS": 321})
        got, meta = service.capture(0, frame=target + 1)
        assert meta["VEXPOS"] == 321 and meta["sensor"] == "MT9P006"
        assert got.image.shape == (480, 640)
        with SMBus(path) as raw:
            word = raw.read_word_data(I2C_ADDRESS, 0x09)
        assert ((word & 0xFF) << 8 | word >> 8) == 321
    finally:
        service.close()
