"""The v4l2 board through the real daemon: capture, parameters, schema, faults, as HTTP."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from typing import Any

import httpx
import numpy as np
import pytest

from elphel_camd.boards.v4l2 import V4L2Board, V4L2Port
from elphel_camd.cli import main as camd_main
from elphel_camd.service import CameraService
from elphel_camd.v4l2.controls import CID_EXPOSURE
from elphel_camd.v4l2.synthetic import SyntheticSource
from elphel_host.camera.frames import read_tiff_pages
from elphel_host.cli import main as host_main
from tests.camd.served import AUTH, serve

HEIGHT, WIDTH = 16, 32
LINE_S = (WIDTH + 168) / 182.4e6  # the synthetic IMX219 controls: HBLANK 168, 182.4 MHz


def _image() -> np.ndarray:
    return np.random.default_rng(3).integers(0, 1024, (HEIGHT, WIDTH), dtype=np.uint16)


class Nodes:
    def __init__(self) -> None:
        self.made: dict[str, SyntheticSource] = {}
        self.gone: set[str] = set()

    def __call__(self, port: V4L2Port) -> SyntheticSource:
        if port.video in self.gone:
            raise OSError(2, f"{port.video}: no such node")
        source = SyntheticSource(_image(), fourcc="pRAA", fps=50.0, path=port.video, pad=8)
        self.made[port.video] = source
        return source


@pytest.fixture
def nodes() -> Nodes:
    return Nodes()


@pytest.fixture
def cam(nodes: Nodes) -> Iterator[tuple[httpx.Client, CameraService]]:
    service = CameraService(
        V4L2Board(["/dev/video0"], open_source=nodes, ring_frames=32, buffers=8)
    )
    try:
        with serve(service) as served, httpx.Client(base_url=served.url, headers=AUTH) as c:
            yield c, service
    finally:
        service.close()


def _capture(c: httpx.Client, **params: Any) -> tuple[np.ndarray, dict[str, Any], httpx.Response]:
    r = c.post("/api/v1/ports/0/capture", params=params, timeout=20)
    assert r.status_code == 200, r.text
    images, metadata = read_tiff_pages(r.content)
    return images[0], metadata[0], r


def test_a_capture_is_the_nodes_frame_with_its_number_time_and_bayer(cam) -> None:
    c, _ = cam
    image, meta, r = _capture(c)
    np.testing.assert_array_equal(image, _image())
    assert meta["bayer"] == "RGGB" and meta["sensor"] == "V4L2"
    assert int(r.headers["X-Frame-Number"]) == meta["frame"] and meta["timestamp_ns"] > 0
    assert meta["EXPOS"] == round(1600 * LINE_S * 1e6)  # the driver's exposure, read back
    _, second, _ = _capture(c, frame=meta["frame"])
    assert second["frame"] == meta["frame"]
    r = c.post("/api/v1/ports/0/capture", params={"count": 3}, timeout=20)
    _, pages = read_tiff_pages(r.content)
    first = pages[0]["frame"]
    assert [p["frame"] for p in pages] == [first, first + 1, first + 2]


def test_preview_histogram_info_and_health_serve_the_port(cam, nodes: Nodes) -> None:
    c, _ = cam
    _capture(c)
    assert c.get("/api/v1/ports/0/preview").headers["content-type"] == "image/jpeg"
    assert c.get("/api/v1/ports/0/histogram").status_code == 200
    mjpeg = c.get("/api/v1/ports/0/preview.mjpeg", params={"count": 2, "fps": 20}, timeout=20)
    assert mjpeg.status_code == 200 and mjpeg.content.count(b"\xff\xd8") == 2
    info = c.get("/api/v1/info").json()
    port = info["ports"][0]
    assert info["board"] == "v4l2" and port["sensor"]["format"] == "pRAA"
    assert port["stream"]["state"] == "streaming"
    # Frames are lost only when the daemon's reader falls behind the node's 8 buffers (a
    # busy machine): health counts no frame the node did not lose (the gap of a loss shows
    # once the frames queued before it are read; injected drops: test_drops_are_events_...).
    health = c.get("/api/v1/health").json()
    assert health["status"] == "ok"
    assert 0 <= health["ports"][0]["stream"]["dropped"] <= nodes.made["/dev/video0"].lost


def test_the_schema_offers_only_what_the_controls_carry(cam) -> None:
    c, _ = cam
    params = c.get("/api/v1/ports/0/params/schema").json()["params"]
    writable = {name for name, spec in params.items() if spec["writable"]}
    assert writable == {"EXPOS", "GAINR", "GAING", "GAINGB", "GAINB", "FLIPH", "FLIPV"}
    assert params["EXPOS"]["maximum"] == round(3522 * LINE_S * 1e6)
    assert params["WOI_WIDTH"]["minimum"] == params["WOI_WIDTH"]["maximum"] == WIDTH


def test_a_patch_sets_the_controls_and_frames_record_what_the_driver_reads_back(
    cam, nodes: Nodes
) -> None:
    c, _ = cam
    _capture(c)
    r = c.patch("/api/v1/ports/0/params", json={"EXPOS": round(100 * LINE_S * 1e6), "FLIPV": 1})
    assert r.status_code == 200, r.text
    applied = r.json()["frame"]
    _, meta, _ = _capture(c, frame=applied + 2)
    assert nodes.made["/dev/video0"].get_controls([CID_EXPOSURE])[CID_EXPOSURE] == 100
    assert meta["EXPOS"] == round(100 * LINE_S * 1e6) and meta["FLIPV"] == 1
    assert meta["bayer"] == "GBRG"  # RGGB read out bottom-up


def test_a_value_the_driver_refuses_is_422_naming_its_limits(cam) -> None:
    c, _ = cam
    r = c.patch("/api/v1/ports/0/params", json={"EXPOS": 2_000_000})
    assert r.status_code == 422, r.text
    body = r.json()
    assert body["error"] == "control_refused" and body["parameter"] == "EXPOS"
    assert "'Exposure' takes 4..3522 step 1" in body["allowed"]
    r = c.patch("/api/v1/ports/0/params", json={"GAINR": 0x20000, "GAINB": 0x30000})
    assert r.status_code == 422 and "one gain for all colours" in r.json()["allowed"]


def test_a_vanished_node_is_503_and_an_event_and_the_port_recovers(cam, nodes: Nodes) -> None:
    c, service = cam
    seen: list[tuple[str, dict[str, Any]]] = []
    sub = service.events.subscribe(("port", "error"))
    _capture(c)
    nodes.gone.add("/dev/video0")
    nodes.made["/dev/video0"].sim_gone = True
    deadline = time.monotonic() + 5
    while c.get("/api/v1/health").json()["status"] == "ok" and time.monotonic() < deadline:
        time.sleep(0.02)
    r = c.post("/api/v1/ports/0/capture")
    assert r.status_code == 503 and r.json()["error"] == "disconnected", r.text
    health = c.get("/api/v1/health")
    assert health.status_code == 503
    assert health.json()["ports"][0]["error"] == "disconnected"
    while (event := sub.pop()) is not None:
        seen.append((event.type, event.data))
    assert ("port", "disconnected") in [(k, d.get("state")) for k, d in seen]
    nodes.gone.clear()
    while c.get("/api/v1/health").json()["status"] != "ok" and time.monotonic() < deadline + 5:
        time.sleep(0.05)
    _capture(c)


def test_no_frame_for_several_periods_is_504(cam, nodes: Nodes) -> None:
    c, _ = cam
    _capture(c)
    _capture(c)
    nodes.made["/dev/video0"].sim_silent = True
    # Buffers the driver filled before it fell silent still come; then nothing does.
    for _ in range(10):
        start = time.monotonic()
        r = c.post("/api/v1/ports/0/capture", timeout=20)
        if r.status_code != 200:
            break
    assert r.status_code == 504, r.text
    assert "5 frame periods of 20.0 ms" in r.json()["detail"]
    assert time.monotonic() - start < 5


def test_the_daemon_refuses_a_missing_node_at_start(capsys: pytest.CaptureFixture[str]) -> None:
    code = camd_main(["--board", "v4l2", "--video", "/dev/video-missing", "--port", "0"])
    assert code == 1
    assert "/dev/video-missing: no such V4L2 node" in capsys.readouterr().err


def test_drops_are_events_and_counted_in_health(cam, nodes: Nodes) -> None:
    c, service = cam
    sub = service.events.subscribe(("error",))
    _capture(c)
    nodes.made["/dev/video0"].sim_drop(3)
    deadline = time.monotonic() + 10
    while c.get("/api/v1/health").json()["ports"][0]["stream"]["dropped"] < 3:
        assert time.monotonic() < deadline, "the three lost frames were not counted"
        time.sleep(0.02)
    events = []
    while (event := sub.pop()) is not None:
        events.append(event.data)
    # three lost here (more if a busy machine made the stream late at the same time)
    assert any(e["error"] == "frames_dropped" and e["frames"] >= 3 for e in events)
    json.dumps(events)  # events are JSON as the stream sends them


def test_the_hosts_camera_commands_work_on_the_v4l2_board(cam, tmp_path, capsys) -> None:
    c, _ = cam
    url, token = str(c.base_url).rstrip("/"), AUTH["Authorization"].split()[1]
    common = ["--camera", url, "--token", token, "--json"]
    assert host_main(["camera", "set", *common, "EXPOS=2000"]) == 0
    out = tmp_path / "burst.tif"
    assert host_main(["camera", "capture", *common, "--count", "3", "--out", str(out)]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert str(out) in json.dumps(summary)  # the command says where the frames went
    _, pages = read_tiff_pages(out.read_bytes())
    assert len(pages) == 3 and all(p["bayer"] == "RGGB" for p in pages)
    assert pages[-1]["EXPOS"] == round(round(2000e-6 / LINE_S) * LINE_S * 1e6)


def test_a_mono_node_gives_frames_without_a_bayer_label() -> None:
    def mono(port: V4L2Port) -> SyntheticSource:
        return SyntheticSource(_image(), fourcc="Y10 ", fps=50.0, path=port.video)

    service = CameraService(V4L2Board(["/dev/video0"], open_source=mono))
    try:
        with serve(service) as served, httpx.Client(base_url=served.url, headers=AUTH) as c:
            image, meta, _ = _capture(c)
            schema = c.get("/api/v1/ports/0/params/schema").json()
            preview = c.get("/api/v1/ports/0/preview")
    finally:
        service.close()
    np.testing.assert_array_equal(image, _image())
    assert meta["bayer"] is None and schema["bayer"] is None
    assert preview.status_code == 200 and preview.headers["content-type"] == "image/jpeg"


def _served(**node: Any) -> tuple[CameraService, Any, list[SyntheticSource]]:
    """A daemon on a synthetic RG10 node; the list gets each node the board opens."""
    made: list[SyntheticSource] = []

    def opener(port: V4L2Port) -> SyntheticSource:
        made.append(SyntheticSource(_image(), fourcc="RG10", fps=50.0, path=port.video, **node))
        return made[-1]

    service = CameraService(V4L2Board(["/dev/video0"], open_source=opener, ring_frames=32))
    return service, serve(service), made


def test_a_window_through_the_drivers_crop_starts_at_the_frame_the_patch_names() -> None:
    service, served_cm, made = _served(crop=True, pad=6)
    try:
        with served_cm as served, httpx.Client(base_url=served.url, headers=AUTH) as c:
            schema = c.get("/api/v1/ports/0/params/schema").json()
            _capture(c)
            r = c.patch(
                "/api/v1/ports/0/params",
                json={"WOI_LEFT": 8, "WOI_TOP": 4, "WOI_WIDTH": 16, "WOI_HEIGHT": 8},
            )
            assert r.status_code == 200, r.text
            first = r.json()["frame"]
            new, meta, _ = _capture(c, frame=first)
            old, before, _ = _capture(c, frame=first - 1)
            refused = c.patch("/api/v1/ports/0/params", json={"WOI_LEFT": 20})
            odd = c.patch("/api/v1/ports/0/params", json={"WOI_TOP": 3})
            health = c.get("/api/v1/health").json()["ports"][0]["stream"]
    finally:
        service.close()
    assert schema["window"] == {"width": WIDTH, "height": HEIGHT, "step": 2}
    woi = ("WOI_LEFT", "WOI_TOP", "WOI_WIDTH", "WOI_HEIGHT")
    assert all(schema["params"][n]["writable"] for n in woi)
    np.testing.assert_array_equal(new, _image()[4:12, 8:24])
    assert [meta[n] for n in woi] == [8, 4, 16, 8] and meta["bayer"] == "RGGB"
    np.testing.assert_array_equal(old, _image())
    assert [before[n] for n in woi] == [0, 0, WIDTH, HEIGHT]
    assert refused.status_code == 422, refused.text
    assert refused.json()["allowed"] == "0..16 (even), inside the driver's crop bounds 32x16"
    assert odd.status_code == 422 and odd.json()["allowed"].startswith("0..8 (even)")
    # The crop change loses no frame: health counts only what the node lost when the
    # daemon's reader fell behind its buffers (a busy machine), and the stream never restarts.
    assert len(made) == 1 and health["restarts"] == 0
    assert 0 <= health["dropped"] <= made[0].lost


def test_a_window_through_the_sensors_modes_is_a_size_it_offers() -> None:
    service, served_cm, _ = _served(sizes=((WIDTH, HEIGHT), (16, 8), (8, 4)))
    try:
        with served_cm as served, httpx.Client(base_url=served.url, headers=AUTH) as c:
            schema = c.get("/api/v1/ports/0/params/schema").json()
            _capture(c)
            r = c.patch("/api/v1/ports/0/params", json={"WOI_WIDTH": 16, "WOI_HEIGHT": 8})
            assert r.status_code == 200, r.text
            first = r.json()["frame"]
            new, meta, _ = _capture(c, frame=first)
            old, _, _ = _capture(c, frame=first - 1)
            refused = c.patch("/api/v1/ports/0/params", json={"WOI_WIDTH": 20, "WOI_HEIGHT": 8})
            offset = c.patch("/api/v1/ports/0/params", json={"WOI_LEFT": 2})
    finally:
        service.close()
    writable = {n for n, spec in schema["params"].items() if spec["writable"]}
    assert {"WOI_WIDTH", "WOI_HEIGHT"} <= writable and not {"WOI_LEFT", "WOI_TOP"} & writable
    assert schema["window"] is None
    assert schema["params"]["WOI_WIDTH"]["minimum"] == 8
    assert schema["params"]["WOI_WIDTH"]["maximum"] == WIDTH
    np.testing.assert_array_equal(new, _image()[:8, :16])
    assert (meta["WOI_WIDTH"], meta["WOI_HEIGHT"]) == (16, 8)
    assert old.shape == (HEIGHT, WIDTH)
    assert refused.status_code == 422
    assert "32x16, 16x8, 8x4" in refused.json()["allowed"]
    assert offset.status_code == 409 and "WOI_LEFT" in offset.json()["detail"]
