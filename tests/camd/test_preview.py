"""Previews for the browser page: binned demosaic, white balance, thermal palette, JPEG,
histogram (pure functions), and their routes on the simulated board (in process)."""

import io

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from elphel_camd import preview
from elphel_camd.api import create_app
from elphel_camd.api.routes import preview as preview_routes
from elphel_camd.service import CameraService
from elphel_sim.board import SimCameraBoard
from elphel_sim.scenarios import build

TOKEN = "test-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
SMALL = {"WOI_WIDTH": 64, "WOI_HEIGHT": 48, "WOI_LEFT": 1200, "WOI_TOP": 900}
RGB = {"R": 1000, "G": 2000, "B": 500}


def mosaic(bayer: str, shape=(32, 48), values=RGB) -> np.ndarray:
    out = np.empty(shape, np.uint16)
    for i, colour in enumerate(bayer):
        out[i // 2 :: 2, i % 2 :: 2] = values[colour]
    return out


@pytest.mark.parametrize("bayer", ["RGGB", "GRBG", "GBRG", "BGGR"])
@pytest.mark.parametrize("factor", [1, 2, 4, 8])
def test_binned_demosaic_recovers_each_colour_of_every_bayer_order(bayer, factor):
    rgb = preview.bayer_rgb(mosaic(bayer), bayer, factor=factor)
    assert rgb.shape == (32 // factor, 48 // factor, 3)
    assert np.array_equal(rgb[..., 0], np.full(rgb.shape[:2], 1000.0))
    assert np.array_equal(rgb[..., 1], np.full(rgb.shape[:2], 2000.0))
    assert np.array_equal(rgb[..., 2], np.full(rgb.shape[:2], 500.0))


def test_a_block_is_the_mean_of_its_cells():
    image = np.random.default_rng(1).integers(0, 4096, (16, 16), dtype=np.uint16)
    rgb = preview.bayer_rgb(image, "GRBG", factor=4)
    red = image[0:4:2, 1:4:2].astype(float).mean()  # the 2 x 2 cells of block (0, 0)
    green = (image[0:4:2, 0:4:2].astype(float).mean() + image[1:4:2, 1:4:2].mean()) / 2
    assert rgb[0, 0, 0] == pytest.approx(red)
    assert rgb[0, 0, 1] == pytest.approx(green)


@pytest.mark.parametrize("factor", [1, 2, 4, 8])
def test_the_fast_preview_matches_demosaic_white_balance_and_tone(factor):
    image = np.random.default_rng(2).integers(0, 4096, (96, 128), dtype=np.uint16)
    image[::2, 1::2] //= 2  # a red tint to balance
    got = preview.preview_rgb(image, factor=factor, bayer="GRBG", bits=12)
    rgb = preview.bayer_rgb(image, "GRBG", factor=factor)
    gains = preview.grey_world_gains(rgb)
    want = preview.tone(rgb * gains, 4095.0)
    assert got.rgb.shape == want.shape
    assert np.abs(got.rgb.astype(int) - want).max() <= 1
    assert got.wb_gains == pytest.approx((gains[0], 1.0, gains[2]), rel=1e-5)


def test_grey_world_makes_a_tinted_uniform_scene_grey():
    got = preview.preview_rgb(mosaic("GRBG"), factor=2, bayer="GRBG", bits=12)
    assert got.wb_gains == pytest.approx((2.0, 1.0, 4.0))
    assert np.ptp(got.rgb.reshape(-1, 3), axis=1).max() <= 1
    off = preview.preview_rgb(mosaic("GRBG"), factor=2, bayer="GRBG", bits=12, white_balance=False)
    r, g, b = off.rgb[0, 0]
    assert b < r < g


def test_preview_rejects_what_it_cannot_show():
    with pytest.raises(ValueError, match="allowed 1, 2, 4, 8"):
        preview.preview_rgb(mosaic("GRBG"), factor=3, bayer="GRBG", bits=12)
    with pytest.raises(ValueError, match="Bayer order"):
        preview.preview_rgb(mosaic("GRBG"), factor=2, bayer="RGBW", bits=12)
    with pytest.raises(ValueError, match="too small"):
        preview.preview_rgb(np.zeros((4, 4), np.uint16), factor=8, bayer="GRBG", bits=12)


def test_thermal_palette_spans_the_given_temperatures():
    frame = np.full((120, 160), 29315, np.uint16)  # 20.00 °C at 0.01 K
    frame[:, 80:] = 30315  # 30.00 °C
    shown = preview.thermal_rgb(frame, kelvin_per_count=0.01, low_c=20.0, high_c=30.0)
    lut = preview.palette_lut()
    assert shown.temperature_c == (20.0, 30.0)
    assert tuple(shown.rgb[0, 0]) == tuple(lut[0])
    assert tuple(shown.rgb[0, -1]) == tuple(lut[-1])
    auto = preview.thermal_rgb(frame, kelvin_per_count=0.01)
    assert auto.temperature_c == (20.0, 30.0)  # the 1st and 99th percentiles
    coarse = preview.thermal_rgb(frame // 10, kelvin_per_count=0.1)
    assert coarse.temperature_c == pytest.approx((19.95, 29.95), abs=0.01)


def test_histogram_counts_every_pixel_and_the_clipped_ones():
    image = mosaic("GRBG", values={"R": 4095, "G": 64, "B": 0})
    h = preview.histogram(image, bayer="GRBG", bits=12)
    assert (h["bins"], h["bin_width"], h["full_scale"]) == (64, 64, 4095)
    ch = h["channels"]
    assert ch["R"]["clipped_high"] == image.size // 4 and ch["R"]["counts"][63] == image.size // 4
    assert ch["G"]["counts"][1] == image.size // 2 and ch["G"]["clipped_high"] == 0
    assert ch["B"]["clipped_low"] == image.size // 4
    assert sum(sum(c["counts"]) for c in ch.values()) == image.size


def test_jpeg_is_a_baseline_jpeg_of_the_image():
    rgb = np.zeros((30, 40, 3), np.uint8)
    rgb[:, :20] = (200, 40, 40)
    data = preview.encode_jpeg(rgb)
    back = np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))
    assert back.shape == (30, 40, 3)
    assert np.abs(back[5, 5].astype(int) - (200, 40, 40)).max() < 12
    with pytest.raises(ValueError, match="uint8"):
        preview.encode_jpeg(rgb.astype(np.float32))


# -- routes on the simulated board ---------------------------------------------------------


@pytest.fixture(scope="module")
def client():
    board = SimCameraBoard(build("mixed", seed=1), seed=1)
    cam = CameraService(board)
    cam.set_params(0, SMALL)
    board.sim_advance(frames=4)
    # Open reads: these tests are about what a preview holds; the token has its own test.
    with TestClient(create_app(cam, token=TOKEN, public_reads=True)) as c:
        yield c
    cam.close()


def test_preview_is_a_jpeg_of_the_next_frame_with_its_number_and_time(client):
    now = client.get("/api/v1/ports/0/frame").json()["frame"]
    r = client.get("/api/v1/ports/0/preview", params={"scale": "1/4"})
    assert r.status_code == 200 and r.headers["content-type"] == "image/jpeg"
    assert int(r.headers["x-frame-number"]) > now
    assert int(r.headers["x-timestamp-ns"]) > 0
    assert (r.headers["x-image-width"], r.headers["x-image-height"]) == ("64", "48")
    assert Image.open(io.BytesIO(r.content)).size == (16, 12)
    frame = int(r.headers["x-frame-number"])
    again = client.get("/api/v1/ports/0/preview", params={"scale": "0.25", "frame": frame})
    assert again.content == r.content  # the same frame, made once


def test_preview_scale_outside_the_allowed_ones_is_422_naming_them(client):
    r = client.get("/api/v1/ports/0/preview", params={"scale": "1/3"})
    assert r.status_code == 422
    body = r.json()
    assert body["parameter"] == "scale" and "1/2" in body["allowed"]


def test_lepton_preview_is_false_colour_with_its_temperatures(client):
    r = client.get("/api/v1/ports/2/preview", params={"scale": "1"})
    assert r.status_code == 200
    low, high = float(r.headers["x-temperature-min-c"]), float(r.headers["x-temperature-max-c"])
    assert -20 < low < high < 60
    assert r.headers["x-palette"].split(",") == list(preview.PALETTE)
    assert Image.open(io.BytesIO(r.content)).size == (160, 120)
    fixed = client.get("/api/v1/ports/2/preview", params={"tmin": 0, "tmax": 40})
    assert (fixed.headers["x-temperature-min-c"], fixed.headers["x-temperature-max-c"]) == (
        "0.00",
        "40.00",
    )


def test_mjpeg_stream_sends_one_part_per_frame_with_its_headers(client):
    with client.stream(
        "GET", "/api/v1/ports/0/preview.mjpeg", params={"count": 3, "fps": 30, "scale": "1/2"}
    ) as r:
        assert r.status_code == 200
        assert r.headers["content-type"] == "multipart/x-mixed-replace; boundary=frame"
        body = r.read()
    parts = body.split(b"--frame\r\n")[1:]
    assert len(parts) == 3
    frames = []
    for part in parts:
        head, jpeg = part.split(b"\r\n\r\n", 1)
        headers = dict(line.split(": ", 1) for line in head.decode().split("\r\n"))
        assert int(headers["Content-Length"]) == len(jpeg) - 2  # the part ends in CRLF
        assert Image.open(io.BytesIO(jpeg[:-2])).size == (32, 24)
        frames.append(int(headers["X-Frame-Number"]))
    assert frames == sorted(frames) and len(set(frames)) == 3


def test_more_streams_than_allowed_get_429(client):
    slots = preview_routes._slots
    taken = 0
    while slots.take():
        taken += 1
    try:
        r = client.get("/api/v1/ports/0/preview.mjpeg", params={"count": 1})
        assert r.status_code == 429 and r.json()["error"] == "too_many_streams"
    finally:
        for _ in range(taken):
            slots.give()
    assert client.get("/api/v1/ports/0/preview.mjpeg", params={"count": 1}).status_code == 200


def test_histogram_of_a_frame(client):
    r = client.get("/api/v1/ports/0/histogram").json()
    assert set(r["channels"]) == {"R", "G", "B"}
    assert sum(sum(c["counts"]) for c in r["channels"].values()) == 64 * 48
    assert r["full_scale"] == 4095


def test_param_schema_gives_limits_units_and_display_per_sensor(client):
    bayer = client.get("/api/v1/ports/0/params/schema").json()
    assert bayer["sensor"] == "MT9P006" and bayer["window"] == {
        "width": 2592,
        "height": 1944,
        "step": 2,
    }
    expos = bayer["params"]["EXPOS"]
    assert expos["writable"] and expos["unit"] == "us" and expos["display"]["unit"] == "ms"
    assert bayer["params"]["WOI_LEFT"]["maximum"] == 2592 - 64
    assert bayer["params"]["GAINR"]["maximum"] == 0xFC000
    assert not bayer["params"]["FRAME"]["writable"]
    lepton = client.get("/api/v1/ports/2/params/schema").json()
    assert lepton["window"] is None and not lepton["params"]["EXPOS"]["writable"]
    assert (lepton["params"]["WOI_WIDTH"]["minimum"], lepton["params"]["WOI_WIDTH"]["maximum"]) == (
        160,
        160,
    )
    assert client.get("/api/v1/ports/3/params/schema").status_code == 404


def test_the_page_is_served_with_a_policy_that_allows_only_this_origin(client):
    r = client.get("/")
    assert r.status_code == 200 and "text/html" in r.headers["content-type"]
    assert "default-src 'self'" in r.headers["content-security-policy"]
    assert '<script type="module" src="/web/main.js">' in r.text
    for name in ("main.js", "api.js", "controls.js", "style.css"):
        assert client.get(f"/web/{name}").status_code == 200
    assert client.get("/web/nothing.js").status_code == 404


def test_previews_need_the_token_unless_reads_are_public():
    board = SimCameraBoard(build("default", seed=1), seed=1)
    cam = CameraService(board)
    cam.set_params(0, SMALL)
    try:
        with TestClient(create_app(cam, token=TOKEN)) as c:
            for path in ("preview", "preview.mjpeg?count=1", "histogram", "params/schema"):
                assert c.get(f"/api/v1/ports/0/{path}").status_code == 401, path
            assert c.get("/api/v1/ports/0/preview", headers=AUTH).status_code == 200
    finally:
        cam.close()
