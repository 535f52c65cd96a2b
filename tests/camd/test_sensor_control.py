"""Sensor control through the daemon's Python API on the simulated board (MT9P006)."""

import numpy as np
import pytest

from elphel_camd.errors import (
    FrameTooEarlyError,
    FrameTooLateError,
    I2CError,
    ParameterRangeError,
    UnsupportedError,
)
from elphel_camd.service import CameraService
from elphel_sim.board import SimCameraBoard
from elphel_sim.scenarios import build

SMALL = {"WOI_LEFT": 1000, "WOI_TOP": 800, "WOI_WIDTH": 128, "WOI_HEIGHT": 96, "EXPOS": 4000}


@pytest.fixture
def camera():
    """Builds (board, service) pairs on the default scenario; each is closed after the test."""
    services = []

    def build_camera(noise=True, ports=1):
        scenario = build("default", seed=3)
        scenario.ports = scenario.ports * ports
        board = SimCameraBoard(scenario, seed=3, noise=noise)
        services.append(CameraService(board))
        return board, services[-1]

    yield build_camera
    for service in services:
        service.close()


def settle(cam, port=0, **params):
    """Apply params and capture until a frame carries them."""
    target = cam.set_params(port, {**SMALL, **params})
    while True:
        frame, meta = cam.capture(port)
        if frame.frame >= target:
            return frame, meta


def test_doubling_expos_doubles_the_signal(camera):
    _, cam = camera()
    one, m1 = settle(cam, EXPOS=2000)
    two, m2 = settle(cam, EXPOS=4000)
    assert m1["EXPOS"] == pytest.approx(2000, abs=11)
    assert m2["EXPOS"] == pytest.approx(2 * m1["EXPOS"], rel=0.01)
    ratio = two.image.mean() / one.image.mean()
    assert ratio == pytest.approx(m2["EXPOS"] / m1["EXPOS"], rel=0.01)


def test_woi_sets_shape_and_origin(camera):
    board, cam = camera(noise=False)
    frame, _ = settle(cam, WOI_LEFT=1000, WOI_TOP=800, WOI_WIDTH=128, WOI_HEIGHT=96)
    assert frame.image.shape == (96, 128)
    # Moving the window by 10 columns shows the same scene 10 columns further on.
    moved, _ = settle(cam, WOI_LEFT=1010, WOI_TOP=800, WOI_WIDTH=128, WOI_HEIGHT=96)
    # Compare same-colour sites (shift by an even number of columns keeps the Bayer phase).
    assert np.array_equal(moved.image[:, :-10], frame.image[:, 10:])
    chip = board.chips[0]
    assert chip.peek("column_start") == 10 + 1010 and chip.peek("column_size") == 127


@pytest.mark.parametrize(("flip", "axis"), [("FLIPH", 1), ("FLIPV", 0)])
def test_flips_mirror_image_and_bayer(camera, flip, axis):
    _, cam = camera(noise=False)
    plain, m0 = settle(cam)
    flipped, m1 = settle(cam, **{flip: 1})
    assert np.array_equal(flipped.image, np.flip(plain.image, axis=axis))
    assert m0["bayer"] == "GRBG"
    assert m1["bayer"] == ("RGGB" if flip == "FLIPH" else "BGGR")


@pytest.mark.parametrize(
    ("gain", "colour"),
    [("GAINR", (0, 1)), ("GAING", (0, 0)), ("GAINGB", (1, 1)), ("GAINB", (1, 0))],
)
def test_each_colour_gain_scales_only_its_colour(camera, gain, colour):
    _, cam = camera(noise=False)
    base, _ = settle(cam, EXPOS=1500)
    gained, meta = settle(cam, EXPOS=1500, **{gain: 0x20000})
    assert meta[gain] == 0x20000
    r, c = colour
    for dr in (0, 1):
        for dc in (0, 1):
            before = base.image[dr::2, dc::2].astype(float).mean()
            after = gained.image[dr::2, dc::2].astype(float).mean()
            expected = 2.0 if (dr, dc) == (r, c) else 1.0
            assert after / before == pytest.approx(expected, rel=0.01), (dr, dc)


def test_gain_residual_is_reported(camera):
    _, cam = camera()
    cam.set_params(0, {"GAINR": 0x1_2345})  # 1.1378x: the analog step is 1/8
    meta = cam.params(0, frame=cam.sequencer(0).this_frame + 3)
    assert meta["GAINR"] == 0x1_2000  # 1.125x, what the code gives


def test_exposure_round_trips_within_one_row(camera):
    _, cam = camera()
    for expos in (37, 1234, 33333, 250_000):
        target = cam.set_params(0, {"EXPOS": expos})
        state = cam.params(0, frame=target)
        row_us = (state["WOI_WIDTH"] + 900) / 96
        assert abs(state["EXPOS"] - expos) <= row_us / 2 + 1
        assert state["VEXPOS"] == max(1, round(expos / row_us))


@pytest.mark.parametrize(
    ("name", "value", "allowed"),
    [
        ("WOI_WIDTH", 2593, "2..2592 (even)"),
        ("WOI_WIDTH", 3, "(even)"),
        ("WOI_LEFT", 2000, "0..0 (even)"),  # full-width window
        ("GAINR", 0x8000, "65536..1032192"),
        ("TRIG", 5, "0 (free-run)"),
        ("TRIG_PERIOD", 100, ">= 256"),
        ("PF_HEIGHT", 3, "(even)"),
        ("EXPOS", 0, "1.."),
        ("FLIPH", 2, "0..1"),
        ("NOSUCH", 1, "one of"),
        ("FP1000S", 1000, "read-only"),
    ],
)
def test_invalid_values_name_parameter_value_and_range_and_change_nothing(
    camera, name, value, allowed
):
    _, cam = camera()
    before = cam.params(0, frame=cam.sequencer(0).this_frame + 5)
    with pytest.raises(ParameterRangeError) as info:
        cam.set_params(0, {"EXPOS": 5000, name: value})
    assert info.value.name == name and info.value.value == value
    assert allowed in str(info.value)
    assert cam.params(0, frame=cam.sequencer(0).this_frame + 5) == before


def test_sequencer_puts_every_change_in_exactly_its_frame(camera):
    """Exposure changes for each upcoming frame, 200+ frames: each image shows its own."""
    board, cam = camera(noise=False)
    cam.set_params(0, SMALL)
    board.sim_advance(frames=4)
    seq = cam.sequencer(0)
    expected: dict[int, int] = {}
    rng = np.random.default_rng(0)
    # A burst of requests for every frame the exposure latency allows (now+3 .. now+14)...
    for k in range(3, 15):
        value = int(rng.integers(500, 4000))
        expected[cam.set_params(0, {"EXPOS": value}, ahead=k)] = value
    checked = 0
    for _ in range(220):
        board.sim_advance(frames=1)
        now = seq.this_frame
        # ...and keep scheduling the newest reachable frame as frames go by.
        value = int(rng.integers(500, 4000))
        expected[cam.set_params(0, {"EXPOS": value}, frame=now + 14)] = value
        record = next(r for r in board.fpga[0].ring if r.frame == now)
        if now in expected:
            regs = record.registers
            rows = regs["shutter_width_lower"] | regs["shutter_width_upper"] << 16
            wanted = cam.params(0, frame=now)
            assert rows == wanted["VEXPOS"], f"frame {now}"
            assert abs(wanted["EXPOS"] - expected[now]) <= 7  # within a row
            checked += 1
    assert checked >= 200


def test_frames_render_the_scheduled_exposure(camera):
    board, cam = camera(noise=False)
    cam.set_params(0, SMALL)
    board.sim_advance(frames=4)
    now = cam.sequencer(0).this_frame
    targets = {now + k: 1000 * k for k in range(3, 9)}
    for frame, expos in targets.items():
        cam.set_params(0, {"EXPOS": expos}, frame=frame)
    means = {}
    for frame in targets:
        image, meta = cam.capture(0, frame=frame)
        means[frame] = image.image.mean() / meta["EXPOS"]
    values = np.array(list(means.values()))
    assert values.max() / values.min() < 1.01


def test_too_late_and_too_early_are_distinct_and_change_nothing(camera):
    board, cam = camera()
    board.sim_advance(frames=3)
    seq = cam.sequencer(0)
    now = seq.this_frame
    before = cam.params(0, frame=now + 14)
    with pytest.raises(FrameTooLateError) as late:
        cam.set_params(0, {"EXPOS": 777}, frame=now + 2)  # exposure needs 2 frames
    assert late.value.earliest == now + 3
    with pytest.raises(FrameTooEarlyError) as early:
        cam.set_params(0, {"EXPOS": 777}, ahead=15)
    assert early.value.latest == now + 14
    assert not isinstance(late.value, FrameTooEarlyError)
    # Gains have latency 1: frame now+2 is fine for them.
    assert cam.set_params(0, {"GAINB": 0x18000}, frame=now + 2) == now + 2
    after = cam.params(0, frame=now + 14)
    assert {k: v for k, v in after.items() if k != "GAINB"} == {
        k: v for k, v in before.items() if k != "GAINB"
    }


def test_all_or_nothing_when_one_value_is_bad(camera):
    _, cam = camera()
    before = cam.params(0, frame=20)
    with pytest.raises(ParameterRangeError):
        cam.set_params(0, {"EXPOS": 1000, "WOI_WIDTH": 5000})
    assert cam.params(0, frame=20) == before


def test_trigger_sync_across_four_ports(camera):
    board, cam = camera(ports=4)
    for port in range(4):
        cam.set_params(port, {**SMALL, "TRIG": 4, "TRIG_DELAY": 1000 * port})
    cam.set_params(0, {"TRIG_PERIOD": 2_000_000})  # 20 ms, 50 fps
    with pytest.raises(ParameterRangeError, match="master port 0"):
        cam.set_params(2, {"TRIG_PERIOD": 1_000_000})
    board.sim_advance(frames=40)
    stamps = {p: [r.timestamp_ns for r in board.fpga[p].ring][-8:] for p in range(4)}
    assert stamps[0] == stamps[1] == stamps[2] == stamps[3]
    assert np.allclose(np.diff(stamps[0]), 20_000_000)
    starts = {p: board.fpga[p].ring[-1].start_s for p in range(4)}
    assert starts[3] - starts[0] == pytest.approx(30e-6)  # each port's own delay
    # Changing the master's period changes every port's frame rate.
    cam.set_params(0, {"TRIG_PERIOD": 4_000_000})
    board.sim_advance(frames=60)
    for p in range(4):
        last = [r.timestamp_ns for r in board.fpga[p].ring][-5:]
        assert np.allclose(np.diff(last), 40_000_000), p
        assert cam.params(p)["FP1000S"] == 25_000


def test_trigger_decimation_per_port(camera):
    board, cam = camera(ports=2)
    for port in range(2):
        cam.set_params(port, {**SMALL, "TRIG": 4})
    cam.set_params(1, {"TRIG_DECIMATE": 1})
    cam.set_params(0, {"TRIG_PERIOD": 2_000_000})
    board.sim_advance(frames=60)
    d0 = np.diff([r.timestamp_ns for r in board.fpga[0].ring][-6:])
    d1 = np.diff([r.timestamp_ns for r in board.fpga[1].ring][-6:])
    assert np.allclose(d0, 20_000_000) and np.allclose(d1, 40_000_000)


def test_fps_limit_stretches_the_frame(camera):
    board, cam = camera()
    cam.set_params(0, {**SMALL, "FP1000SLIM": 50_000, "FPSFLAGS": 1})
    board.sim_advance(frames=8)
    starts = [r.start_s for r in board.fpga[0].ring][-4:]
    assert np.allclose(np.diff(starts), 0.02, rtol=0.01)
    assert cam.params(0)["FP1000S"] == pytest.approx(50_000, rel=0.01)
    # A limit the blanking cannot reach at this window is refused with the lowest possible.
    with pytest.raises(ParameterRangeError, match=">= 4"):
        cam.set_params(0, {"FP1000SLIM": 5000})


def test_nak_is_retried_and_persistent_fault_is_typed_and_shadow_stays_true(camera):
    board, cam = camera()
    driver = cam.sensor(0)
    board.bus(0).sim_nak(1)
    cam.set_params(0, {"GAINB": 0x30000})
    board.sim_advance(frames=3)
    assert driver.io.nak_count >= 1
    assert board.chips[0].peek("blue_gain") == driver.shadow["blue_gain"]
    board.bus(0).sim_stuck()
    with pytest.raises(I2CError) as info:
        driver.write("red_gain", 0x10)
    assert info.value.bus == "port 0" and info.value.address == 0x48
    assert info.value.register == 0x2D
    board.bus(0).sim_stuck(False)
    board.sim_advance(frames=3)  # the sequencer rewrites what the shadow lost
    for name in ("red_gain", "blue_gain", "shutter_width_lower", "row_size"):
        assert board.chips[0].peek(name) == driver.shadow[name], name


def test_daemon_survives_stuck_bus_during_frames(camera):
    board, cam = camera()
    cam.set_params(0, {"GAINB": 0x20000})
    board.bus(0).sim_stuck()
    board.sim_advance(frames=3)  # frame syncs still served; errors recorded, not raised
    assert any("port 0" in e and "0x2c" in e for e in cam.sequencer(0).errors)
    board.bus(0).sim_stuck(False)
    board.sim_advance(frames=2)
    assert board.chips[0].peek("blue_gain") == cam.sensor(0).shadow["blue_gain"] == 0x10


def test_unsupported_on_bare_i2c_board():
    class NoFpga(SimCameraBoard):
        capabilities = frozenset({"frames", "capture"})

    cam = CameraService(NoFpga(build("default", seed=0)))
    try:
        with pytest.raises(UnsupportedError, match="trigger"):
            cam.set_params(0, {"TRIG_PERIOD": 100_000})
    finally:
        cam.close()


def test_frame_truth_records_the_carriage_position_of_each_frame(camera):
    board, cam = camera()
    cam.set_params(0, SMALL)
    board.world.rig.carriage_mm = 12.5
    board.sim_advance(frames=1)
    first = board.fpga[0].frame
    board.world.rig.carriage_mm = 13.0
    board.sim_advance(frames=1)
    assert board.sim_frame_truth(0, first)["carriage_mm"] == 12.5
    truth = board.sim_frame_truth(0, first + 1)
    assert truth["carriage_mm"] == 13.0 and truth["camera_position_mm"][0] == 13.0


def test_vexpos_sets_rows_and_the_frame_shows_it(camera):
    board, cam = camera(noise=False)
    frame_a, m1 = settle(cam, EXPOS=2000)
    target = cam.set_params(0, {"VEXPOS": 2 * m1["VEXPOS"]})
    while (got := cam.capture(0))[0].frame < target:
        pass
    frame_b, meta = got
    assert meta["VEXPOS"] == 2 * m1["VEXPOS"]
    assert meta["EXPOS"] == pytest.approx(2 * m1["EXPOS"], abs=1)
    assert frame_b.image.mean() / frame_a.image.mean() == pytest.approx(2.0, rel=0.01)
    record = next(r for r in board.fpga[0].ring if r.frame == frame_b.frame)
    assert record.registers["shutter_width_lower"] == 2 * m1["VEXPOS"]


def test_keep_fps_flag_refuses_exposure_longer_than_the_frame(camera):
    board, cam = camera()
    cam.set_params(0, {**SMALL, "FP1000SLIM": 50_000, "FPSFLAGS": 3})
    board.sim_advance(frames=6)
    with pytest.raises(ParameterRangeError, match="FPSFLAGS bit 1"):
        cam.set_params(0, {"EXPOS": 30_000})  # a 20 ms frame cannot hold 30 ms
    # Without the flag the same exposure lengthens the frame instead.
    cam.set_params(0, {"FPSFLAGS": 1, "EXPOS": 30_000})
    board.sim_advance(frames=8)
    starts = [r.start_s for r in board.fpga[0].ring][-3:]
    assert np.diff(starts).min() > 0.03
