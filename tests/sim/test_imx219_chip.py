"""The simulated IMX219: real smbus2 transfers with 16-bit addresses, latencies, images.

The daemon's driver runs unchanged on the simulated chip (scenario ``pi-pair``).
"""

import numpy as np
import pytest
from fastapi.testclient import TestClient
from smbus2 import i2c_msg

from elphel_camd.api import create_app
from elphel_camd.errors import PortError
from elphel_camd.sensors import IMX219
from elphel_camd.service import CameraService
from elphel_sim.board import SimCameraBoard
from elphel_sim.chips.bus import SimI2CBus
from elphel_sim.chips.imx219 import SimIMX219, bin_bayer
from elphel_sim.launcher import serve_daemons
from elphel_sim.port_view import PortView
from elphel_sim.scenarios import PI_PAIR_BASELINE_MM, Scenario, build
from elphel_sim.world import Rig, World

SMALL = {"WOI_LEFT": 1512, "WOI_TOP": 1136, "WOI_WIDTH": 128, "WOI_HEIGHT": 96, "EXPOS": 3000}
_PAIR = build("pi-pair", seed=5)


def chip_on_bus():
    chip = SimIMX219()
    bus = SimI2CBus()
    bus.attach(0x10, chip)
    return chip, bus


def test_writes_and_reads_are_bytes_at_16bit_addresses_auto_incrementing():
    chip, bus = chip_on_bus()
    bus.i2c_rdwr(i2c_msg.write(0x10, b"\x01\x5a\x02\x11"))  # coarse integration = 0x0211
    assert chip.peek("coarse_integration_time") == 0x0211
    bus.i2c_rdwr(i2c_msg.write(0x10, b"\x01\x57\x80\x01\x80"))  # gain code, then digital gain
    assert (chip.peek("analogue_gain"), chip.peek("digital_gain")) == (0x80, 0x0180)
    where, got = i2c_msg.write(0x10, b"\x01\x57"), i2c_msg.read(0x10, 3)
    bus.i2c_rdwr(where, got)
    assert bytes(got) == b"\x80\x01\x80"


def test_chip_id_is_read_only_and_undeclared_bytes_read_back():
    _, bus = chip_on_bus()
    bus.i2c_rdwr(i2c_msg.write(0x10, b"\x00\x00\x12\x34\x30\x00\x5a"))
    where, got = i2c_msg.write(0x10, b"\x00\x00"), i2c_msg.read(0x10, 2)
    bus.i2c_rdwr(where, got)
    assert bytes(got) == b"\x02\x19"
    bus.i2c_rdwr(i2c_msg.write(0x10, b"\x30\x00\x5a"))
    where, got = i2c_msg.write(0x10, b"\x30\x00"), i2c_msg.read(0x10, 1)
    bus.i2c_rdwr(where, got)
    assert bytes(got) == b"\x5a"


def test_exposure_reaches_the_image_two_frames_later_and_gains_one():
    chip, bus = chip_on_bus()
    before = chip.image_register("coarse_integration_time")
    chip.latch(10)
    bus.i2c_rdwr(i2c_msg.write(0x10, b"\x01\x5a\x00\x40"))
    bus.i2c_rdwr(i2c_msg.write(0x10, b"\x01\x57\x80"))
    chip.latch(11)
    assert chip.image_register("coarse_integration_time") == before
    assert chip.image_register("analogue_gain") == 0x80
    chip.latch(12)
    assert chip.image_register("coarse_integration_time") == 0x40


def test_a_chip_in_standby_starts_no_frame_until_it_streams():
    chip, bus = chip_on_bus()
    assert chip.is_snapshot()
    bus.i2c_rdwr(i2c_msg.write(0x10, b"\x01\x00\x01"))
    assert not chip.is_snapshot()


def test_binning_keeps_the_bayer_order_at_half_the_size():
    image = np.zeros((8, 8), dtype=np.uint16)
    image[0::2, 0::2] = 100  # R
    image[1::2, 1::2] = 10  # B
    binned = bin_bayer(image, horizontal=True, vertical=True)
    assert binned.shape == (4, 4)
    assert (binned[0::2, 0::2] == 100).all() and (binned[1::2, 1::2] == 10).all()


@pytest.fixture
def camera():
    """Builds (board, service) pairs on the pi-pair rig; each is closed after the test."""
    services = []

    def build_camera():
        rig = _PAIR.world.rig
        world = World(_PAIR.world.scene, Rig(axis=rig.axis, mounts=dict(rig.mounts)))
        board = SimCameraBoard(Scenario(world, list(_PAIR.ports)), seed=5, noise=False)
        services.append(CameraService(board))
        return board, services[-1]

    yield build_camera
    for service in services:
        service.close()


def settle(cam, port=0, **params):
    target = cam.set_params(port, {**SMALL, **params})
    return cam.capture(port, frame=target)


def test_pi_pair_has_two_imx219_a_baseline_apart(camera):
    board, cam = camera()
    assert all(isinstance(cam.sensor(p), IMX219) for p in (0, 1))
    mounts = board.world.rig.mounts
    assert mounts["cam1"].offset_mm[0] - mounts["cam0"].offset_mm[0] == PI_PAIR_BASELINE_MM
    assert all(m.on_stage for m in mounts.values())


def test_window_flips_gain_and_exposure_through_the_daemon(camera):
    _, cam = camera()
    got, meta = settle(cam)
    base = got.image.astype(float)
    assert base.shape == (96, 128) and meta["bayer"] == "RGGB" and base.max() <= 1023
    red, blue = base[0::2, 0::2].mean(), base[1::2, 1::2].mean()
    assert red / blue == pytest.approx(0.9 / 0.8, rel=0.05)  # the wall's albedo
    flipped, meta = settle(cam, FLIPH=1, FLIPV=1)
    assert meta["bayer"] == "BGGR"
    assert np.array_equal(flipped.image, got.image[::-1, ::-1])
    doubled, meta = settle(cam, FLIPH=0, FLIPV=0, GAING=0x20000)
    assert meta["GAINR"] == 0x20000
    assert doubled.image.mean() / base.mean() == pytest.approx(2.0, rel=0.01)
    longer, meta = settle(cam, GAING=0x10000, EXPOS=6000)
    assert longer.image.mean() / base.mean() == pytest.approx(2.0, rel=0.01)


def test_binning_through_the_daemon_halves_the_frame_averaging_same_colours(camera):
    _, cam = camera()
    full, _ = settle(cam)
    binned, meta = settle(cam, BIN_HOR=2, BIN_VERT=2)
    assert binned.image.shape == (48, 64) and meta["bayer"] == "RGGB"
    assert (meta["WOI_WIDTH"], meta["BIN_HOR"], meta["BIN_VERT"]) == (128, 2, 2)
    expected = bin_bayer(full.image, horizontal=True, vertical=True)
    np.testing.assert_array_equal(binned.image, expected)
    across, meta = settle(cam, BIN_HOR=2, BIN_VERT=1)
    assert across.image.shape == (96, 64)


def test_rest_schema_offers_what_the_imx219_can_set(camera):
    _, cam = camera()
    client = TestClient(create_app(cam, token="t", public_reads=True))
    schema = client.get("/api/v1/ports/1/params/schema").json()
    assert schema["sensor"] == "IMX219" and schema["bayer"] == "RGGB"
    assert schema["window"] == {"width": 3280, "height": 2464, "step": 2}
    params = schema["params"]
    assert params["GAINB"]["writable"] and params["EXPOS"]["writable"]
    assert not params["TRIG_PERIOD"]["writable"] and not params["PF_HEIGHT"]["writable"]
    assert (params["VEXPOS"]["minimum"], params["VEXPOS"]["maximum"]) == (4, 65531)
    assert params["WOI_LEFT"]["maximum"] == 0  # the whole width is read
    refused = client.patch(
        "/api/v1/ports/1/params",
        json={"GAINR": 0x20000, "GAINB": 0x30000},
        headers={"Authorization": "Bearer t"},
    )
    assert refused.status_code == 409, refused.text  # allowed by the schema, not the sensor
    answer = refused.json()
    assert (answer["parameter"], answer["value"]) == ("GAINB", 0x30000)
    assert "one gain for all colours" in answer["allowed"]


def test_a_port_view_is_port_0_of_its_own_board(camera):
    board, _ = camera()
    view = PortView(board, 1)
    cam = CameraService(view)
    assert list(view.buses()) == [0] and "trigger" not in view.capabilities
    got, meta = settle(cam, port=0)
    assert meta["port"] == 0 and board.sim_frame_truth(1, got.frame)["port"] == 1
    with pytest.raises(PortError, match=r"port 1 does not exist; ports: \[0\]"):
        view.capture(1)
    with pytest.raises(PortError, match="port 2 has no simulated sensor"):
        PortView(board, 2)


def test_pi_pair_daemons_are_elphel_camd_only(camera):
    board, _ = camera()
    board.daemon_per_port = True
    with pytest.raises(ValueError, match="allowed: camd"):
        serve_daemons(board, firmware="elphel", port=0, public_reads=False)
