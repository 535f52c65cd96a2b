"""MT9F002 and Lepton 3.5 through the daemon's Python API on the simulated "mixed" board.

Port 0 is an MT9P006, port 1 an MT9F002, port 2 a Lepton 3.5 (scenario "mixed").
"""

import numpy as np
import pytest
from fastapi.testclient import TestClient

from elphel_camd.api import create_app
from elphel_camd.errors import (
    FrameTooLateError,
    LeptonError,
    ParameterRangeError,
    UnsupportedError,
)
from elphel_camd.i2c import RegisterIO
from elphel_camd.sensors import MT9F002, Lepton35, cci
from elphel_camd.sensors import mt9f002 as f002
from elphel_camd.service import CameraService
from elphel_sim.board import SimCameraBoard
from elphel_sim.chips.bus import SimI2CBus
from elphel_sim.chips.lepton35 import SimLepton35
from elphel_sim.scenarios import Scenario, build
from elphel_sim.world import Rig, World

F = 1  # the MT9F002's port
L = 2  # the Lepton's port
SMALL = {"WOI_LEFT": 1000, "WOI_TOP": 800, "WOI_WIDTH": 128, "WOI_HEIGHT": 96, "EXPOS": 2000}


_MIXED = build("mixed", seed=3)


@pytest.fixture
def camera():
    """Builds (board, service) pairs on the mixed board; each is closed after the test."""
    services = []

    def build_camera(noise=True):
        # A fresh rig and clock each time, sharing the scene (and its filtered textures).
        rig = _MIXED.world.rig
        world = World(_MIXED.world.scene, Rig(axis=rig.axis, mounts=dict(rig.mounts)))
        board = SimCameraBoard(Scenario(world, list(_MIXED.ports)), seed=3, noise=noise)
        services.append(CameraService(board))
        return board, services[-1]

    yield build_camera
    for service in services:
        service.close()


def settle(cam, port=F, **params):
    """Apply params and fetch the first frame that carries them (no other frame is formed)."""
    target = cam.set_params(port, {**SMALL, **params})
    return cam.capture(port, frame=target)


# -- MT9F002 ------------------------------------------------------------------------------


def test_mixed_board_detects_each_model(camera):
    _, cam = camera()
    assert isinstance(cam.sensor(F), MT9F002)
    assert isinstance(cam.sensor(L), Lepton35)
    assert cam.sensor(0).model == "MT9P006"
    with pytest.raises(LookupError, match="port 3: no sensor"):
        cam.sensor(3)


def test_mt9f002_woi_sets_shape_and_origin(camera):
    board, cam = camera(noise=False)
    frame, meta = settle(cam)
    assert frame.image.shape == (96, 128)
    assert meta["sensor"] == "MT9F002" and meta["bayer"] == "GRBG"
    moved, _ = settle(cam, WOI_LEFT=1010, WOI_TOP=804)
    # The window moved 10 columns and 4 rows: the same scene, shifted by as much.
    assert np.array_equal(moved.image[:-4, :-10], frame.image[4:, 10:])
    chip = board.chips[F]
    assert chip.peek("x_addr_start") == f002.CLEAR_LEFT + 1010
    assert chip.peek("x_addr_end") == f002.CLEAR_LEFT + 1010 + 127
    assert chip.peek("y_addr_start") == f002.CLEAR_TOP + 804
    assert chip.peek("y_addr_end") == f002.CLEAR_TOP + 804 + 95
    assert (chip.peek("x_output_size"), chip.peek("y_output_size")) == (128, 96)


def test_mt9f002_doubling_expos_doubles_the_signal(camera):
    _, cam = camera()
    one, m1 = settle(cam, EXPOS=1500)
    two, m2 = settle(cam, EXPOS=3000)
    assert m1["EXPOS"] == pytest.approx(1500, abs=6)  # a row is 10.7 us at this width
    assert m2["EXPOS"] == pytest.approx(2 * m1["EXPOS"], rel=0.01)
    ratio = two.image.mean() / one.image.mean()
    assert ratio == pytest.approx(m2["EXPOS"] / m1["EXPOS"], rel=0.01)


def test_mt9f002_exposure_round_trips_within_one_row_with_the_wide_row_quirk(camera):
    _, cam = camera()
    for width, row_clocks in ((128, 0x930), (912, 2 * 0x4C8), (4096, 2 * (2048 + 0x5E))):
        row_us = row_clocks / 220
        for expos in (37, 1234, 33333, 250_000):
            target = cam.set_params(F, {"WOI_WIDTH": width, "WOI_LEFT": 0, "EXPOS": expos})
            state = cam.params(F, frame=target)
            assert state["VEXPOS"] == max(1, round(expos / row_us)), (width, expos)
            assert abs(state["EXPOS"] - expos) <= row_us / 2 + 1


@pytest.mark.parametrize(("flip", "axis"), [("FLIPH", 1), ("FLIPV", 0)])
def test_mt9f002_flips_mirror_image_and_bayer(camera, flip, axis):
    board, cam = camera(noise=False)
    plain, m0 = settle(cam)
    flipped, m1 = settle(cam, **{flip: 1})
    assert np.array_equal(flipped.image, np.flip(plain.image, axis=axis))
    assert m0["bayer"] == "GRBG"
    expected = "RGGB" if flip == "FLIPH" else "BGGR"
    assert m1["bayer"] == expected
    # The chip's pixel_order register reports the same colour for the first pixel.
    assert f002.PIXEL_ORDERS[board.chips[F].peek("pixel_order")] == expected
    assert board.chips[F].peek("read_mode") & 0xC000 == (0x4000 if flip == "FLIPH" else 0x8000)


@pytest.mark.parametrize(
    ("gain", "colour"),
    [("GAINR", (0, 1)), ("GAING", (0, 0)), ("GAINGB", (1, 1)), ("GAINB", (1, 0))],
)
def test_mt9f002_each_colour_gain_scales_only_its_colour(camera, gain, colour):
    _, cam = camera(noise=False)
    base, _ = settle(cam, EXPOS=1000)  # all gains 1.5x
    gained, meta = settle(cam, EXPOS=1000, **{gain: 0x30000})
    assert meta[gain] == 0x30000
    r, c = colour
    for dr in (0, 1):
        for dc in (0, 1):
            before = base.image[dr::2, dc::2].astype(float).mean()
            after = gained.image[dr::2, dc::2].astype(float).mean()
            expected = 2.0 if (dr, dc) == (r, c) else 1.0
            assert after / before == pytest.approx(expected, rel=0.01), (dr, dc)


def test_mt9f002_gain_code_and_residual(camera):
    board, cam = camera()
    target = cam.set_params(F, {"GAINR": 0x2_2345})  # 2.1378x: analog2 steps by 1/32
    assert cam.params(F, frame=target)["GAINR"] == 0x2_2000  # 2.125x, what the code gives
    board.sim_advance(frames=4, port=F)
    assert board.chips[F].peek("red_gain") == 0x1000 | 1 << 10 | 68
    with pytest.raises(ParameterRangeError, match=r"98304\.\.1040384"):
        cam.set_params(F, {"GAINB": 0x10000})  # below the 1.5x analog minimum


def test_mt9f002_sequencer_puts_every_exposure_change_in_exactly_its_frame(camera):
    board, cam = camera(noise=False)
    cam.set_params(F, SMALL)
    board.sim_advance(frames=4, port=F)
    seq = cam.sequencer(F)
    expected: dict[int, int] = {}
    rng = np.random.default_rng(0)
    for k in range(3, 15):
        value = int(rng.integers(500, 4000))
        expected[cam.set_params(F, {"EXPOS": value}, ahead=k)] = value
    checked = 0
    for _ in range(210):
        board.sim_advance(frames=1, port=F)
        now = seq.this_frame
        value = int(rng.integers(500, 4000))
        expected[cam.set_params(F, {"EXPOS": value}, frame=now + 14)] = value
        record = next(r for r in board.fpga[F].ring if r.frame == now)
        if now in expected:
            wanted = cam.params(F, frame=now)
            regs = record.registers
            assert regs["coarse_integration_time"] == wanted["VEXPOS"], f"frame {now}"
            assert regs["frame_length_lines"] > regs["coarse_integration_time"]
            assert abs(wanted["EXPOS"] - expected[now]) <= 6  # within half a row
            checked += 1
    assert checked >= 200


def test_mt9f002_frames_render_their_scheduled_exposure(camera):
    board, cam = camera(noise=False)
    cam.set_params(F, SMALL)
    board.sim_advance(frames=4, port=F)
    now = cam.sequencer(F).this_frame
    targets = {now + k: 500 * k for k in range(3, 9)}
    for frame, expos in targets.items():
        cam.set_params(F, {"EXPOS": expos}, frame=frame)
    per_us = []
    for frame in targets:
        image, meta = cam.capture(F, frame=frame)
        per_us.append(image.image.mean() / meta["EXPOS"])
    assert max(per_us) / min(per_us) < 1.01


def test_mt9f002_exposure_latency_is_two_frames_in_both_modes(camera):
    board, cam = camera()
    board.sim_advance(frames=3, port=F)
    now = cam.sequencer(F).this_frame
    with pytest.raises(FrameTooLateError):
        cam.set_params(F, {"EXPOS": 777}, frame=now + 2)
    assert cam.set_params(F, {"GAINB": 0x20000}, frame=now + 2) == now + 2
    assert cam.sensor(F).latency("exposure", {"TRIG": 4}) == 2


def test_mt9f002_long_exposure_lengthens_the_frame_and_fps_limit_stretches_it(camera):
    board, cam = camera()
    cam.set_params(F, {**SMALL, "EXPOS": 50_000})
    board.sim_advance(frames=8, port=F)
    starts = [r.start_s for r in board.fpga[F].ring][-3:]
    state = cam.params(F)
    assert np.allclose(np.diff(starts), (state["VEXPOS"] + 1) * 0x930 / 220e6, rtol=1e-6)
    assert board.chips[F].peek("frame_length_lines") == state["VEXPOS"] + 1
    cam.set_params(F, {"EXPOS": 1000, "FP1000SLIM": 20_000, "FPSFLAGS": 1})
    board.sim_advance(frames=8, port=F)
    starts = [r.start_s for r in board.fpga[F].ring][-3:]
    assert np.allclose(np.diff(starts), 0.05, rtol=1e-3)
    assert cam.params(F)["FP1000S"] == pytest.approx(20_000, rel=1e-3)


def test_mt9f002_trigger_mode_sets_slave_mode_and_follows_the_trigger(camera):
    board, cam = camera()
    cam.set_params(F, {**SMALL, "EXPOS": 1000, "TRIG": 4})
    cam.set_params(0, {"WOI_WIDTH": 128, "WOI_HEIGHT": 96, "TRIG": 4, "EXPOS": 1000})
    cam.set_params(0, {"TRIG_PERIOD": 2_000_000})  # 20 ms on the master port 0
    board.sim_advance(frames=12, port=F)
    assert board.chips[F].peek("slave_mode") == 0xA000
    assert board.chips[F].is_snapshot()
    stamps = [r.timestamp_ns for r in board.fpga[F].ring][-4:]
    assert np.allclose(np.diff(stamps), 20_000_000)
    # Frame length: the trigger period in rows minus one (reference 2.4).
    assert board.chips[F].peek("frame_length_lines") == 2_000_000 * 22 // 10 // 0x930 - 1
    cam.set_params(F, {"TRIG": 0})
    board.sim_advance(frames=6, port=F)
    assert board.chips[F].peek("slave_mode") == 0x2000


def test_mt9f002_init_writes_elphel_list_first(camera):
    board, _ = camera()
    chip = board.chips[F]
    init = [(f002.TABLE[name].address, value) for name, value in f002.INIT_WRITES]
    assert chip.write_log[: len(init)] == init
    assert chip.peek("pll_multiplier") == 0xB4 and chip.peek("reset_register") == 0x011C


def test_mt9f002_photo_finish_stacks_strips(camera):
    board, cam = camera(noise=False)
    target = cam.set_params(F, {**SMALL, "PF_HEIGHT": 2, "WOI_HEIGHT": 16})
    frame, meta = cam.capture(F, frame=target)
    assert frame.image.shape == (16, 128)
    assert board.chips[F].peek("y_output_size") == 2
    assert meta["PF_HEIGHT"] == 2


@pytest.mark.parametrize(
    ("name", "value", "allowed"),
    [
        ("WOI_WIDTH", 4386, "2..4384 (even)"),
        ("WOI_TOP", 3, "(even)"),
        ("GAINR", 0xFF000, "98304..1040384"),
        ("TRIG", 5, "0 (free-run)"),
        ("VEXPOS", 0x10000, "1..65534"),
    ],
)
def test_mt9f002_invalid_values_name_parameter_value_and_range(camera, name, value, allowed):
    _, cam = camera()
    before = cam.params(F, frame=cam.sequencer(F).this_frame + 5)
    with pytest.raises(ParameterRangeError) as info:
        cam.set_params(F, {name: value})
    assert info.value.name == name and info.value.value == value
    assert allowed in str(info.value)
    assert cam.params(F, frame=cam.sequencer(F).this_frame + 5) == before


# -- Lepton 3.5 ---------------------------------------------------------------------------


def test_lepton_ping_fpa_temperature_and_identity(camera):
    board, cam = camera()
    lepton = cam.sensor(L)
    lepton.ping()
    board.chips[L].sim_fpa_temperature_k = 301.37
    assert lepton.fpa_temperature_k() == pytest.approx(301.37)
    info = cam.info()["ports"][L]["sensor"]
    assert info["model"] == "LEPTON35" and info["bayer"] is None and info["bits"] == 16
    assert info["sensor_code"] == 0x44


def test_lepton_init_sets_vsync_and_telemetry_per_elphel(camera):
    board, cam = camera()
    lepton = cam.sensor(L)
    assert lepton.gpio_mode() == 5
    assert not lepton.telemetry()
    assert board.chips[L].attributes["SYS_TELEMETRY_LOCATION"] == 1
    lepton.set_vsync(False)
    assert lepton.gpio_mode() == 0 == board.chips[L].attributes["OEM_GPIO_MODE"]
    lepton.set_vsync(True)
    assert lepton.gpio_mode() == 5


def test_lepton_ffc_and_radiometry_settings(camera):
    board, cam = camera()
    lepton = cam.sensor(L)
    lepton.run_ffc()
    assert board.chips[L].ffc_count == 1
    assert lepton.radiometry() and lepton.tlinear()
    assert lepton.tlinear_resolution_k() == 0.01
    lepton.set_tlinear_resolution_k(0.1)
    assert lepton.tlinear_resolution_k() == 0.1
    with pytest.raises(ParameterRangeError, match=r"0\.01 or 0\.1"):
        lepton.set_tlinear_resolution_k(0.5)


def test_lepton_capture_is_160x120_mono_uint16_tlinear(camera):
    _, cam = camera()
    frame, meta = cam.capture(L)
    assert frame.image.shape == (120, 160) and frame.image.dtype == np.uint16
    assert meta["bayer"] is None and meta["sensor"] == "LEPTON35"
    assert meta["FP1000S"] == 8700 and meta["WOI_WIDTH"] == 160
    kelvin = frame.image / 100
    assert kelvin.min() >= 283 and kelvin.max() <= 304  # the wall, mapped to 10..30 C
    # 0.1 K resolution: the same scene in tenfold coarser counts.
    cam.sensor(L).set_tlinear_resolution_k(0.1)
    coarse, _ = cam.capture(L)
    assert coarse.image.mean() == pytest.approx(frame.image.mean() / 10, rel=0.01)


def test_lepton_frame_rate_is_8_7_fps(camera):
    board, _ = camera()
    board.sim_advance(frames=4, port=L)
    starts = [r.start_s for r in board.fpga[L].ring][-3:]
    assert np.allclose(np.diff(starts), 1 / 8.7)


def test_lepton_telemetry_rows_follow_woi_height(camera):
    board, cam = camera(noise=False)
    target = cam.set_params(L, {"WOI_HEIGHT": 122})
    frame, _ = cam.capture(L, frame=target)
    assert frame.image.shape == (122, 160)
    footer = frame.image[120]
    assert footer[24] == board.chips[L].image_registers()["FPA_CENTI_K"]
    assert footer[20] | footer[21] << 16 == target
    assert cam.sensor(L).telemetry()
    target = cam.set_params(L, {"WOI_HEIGHT": 120})
    assert cam.capture(L, frame=target)[0].image.shape == (120, 160)


@pytest.mark.parametrize(
    ("name", "value", "match"),
    [
        ("WOI_WIDTH", 100, "fixed at 160x120"),
        ("WOI_HEIGHT", 96, "fixed at 160x120"),
        ("WOI_LEFT", 2, "fixed at 160x120"),
        ("TRIG", 4, "no trigger input"),
    ],
)
def test_lepton_fixed_parameters_are_range_errors(camera, name, value, match):
    _, cam = camera()
    with pytest.raises(ParameterRangeError, match=match) as info:
        cam.set_params(L, {name: value})
    assert info.value.name == name and info.value.value == value


@pytest.mark.parametrize(
    ("name", "match"),
    [
        ("EXPOS", "without exposure control"),
        ("GAINR", "no colour gains"),
        ("FLIPH", "does not mirror"),
        ("PF_HEIGHT", "no photo-finish"),
        ("FP1000SLIM", "fixed at 8.7 fps"),
    ],
)
def test_lepton_unsupported_parameters_say_why(camera, name, match):
    _, cam = camera()
    with pytest.raises(UnsupportedError, match=f"LEPTON35 does not support setting {name}"):
        cam.set_params(L, {name: 2})
    with pytest.raises(UnsupportedError, match=match):
        cam.set_params(L, {name: 2})


def test_common_trigger_period_reaches_the_lepton_port_unchanged(camera):
    _, cam = camera()
    cam.set_params(0, {"TRIG_PERIOD": 2_000_000})
    target = cam.sequencer(L).this_frame + 2
    assert cam.params(L, frame=target)["TRIG_PERIOD"] == 2_000_000


def test_lepton_error_code_names_the_command(camera):
    _, cam = camera()
    lepton = cam.sensor(L)
    bad = cci.Command("BOGUS", cci.Module.SYS, 0xF0, 1, frozenset({cci.CommandType.GET}))
    with pytest.raises(LeptonError) as info:
        lepton.cci.get(bad)
    assert info.value.code == -7 and info.value.command == 0x02F0
    assert "0x02f0" in str(info.value) and "undefined function" in str(info.value)


def test_rest_info_lists_all_three_models(camera):
    _, cam = camera()
    client = TestClient(create_app(cam, token="t", public_reads=True))
    answer = client.get("/api/v1/info")
    assert answer.status_code == 200
    models = [p["sensor"]["model"] if p["sensor"] else None for p in answer.json()["ports"]]
    assert models == ["MT9P006", "MT9F002", "LEPTON35", None]
    refused = client.patch(
        f"/api/v1/ports/{L}/params", json={"WOI_WIDTH": 100}, headers={"Authorization": "Bearer t"}
    )
    assert refused.status_code == 409  # allowed by the schema, refused by the Lepton
    assert "fixed at 160x120" in refused.json()["detail"]


def test_rest_raw_registers_of_the_lepton_are_its_cci_interface(camera):
    _, cam = camera()
    client = TestClient(create_app(cam, token="t", public_reads=True))
    table = client.get(f"/api/v1/ports/{L}/registers")
    assert table.status_code == 200
    names = [r["name"] for r in table.json()]
    assert names[:4] == ["power", "status", "command", "data_length"]
    status = next(r for r in table.json() if r["name"] == "status")
    assert {f["name"] for f in status["fields"]} >= {"busy", "boot_mode", "booted", "error"}
    read = client.get(f"/api/v1/ports/{L}/registers/0x0002")
    assert read.status_code == 200
    assert read.json()["value"] == cci.STATUS_READY
    assert read.json()["fields"]["busy"] == 0 and read.json()["fields"]["booted"] == 1
    # The register-file sensors show their fields too, decoded from the value read.
    assert cam.sensor(F).fields_of("read_mode", 0xC041)["flip_vertical"] == 1
    mode = client.get(f"/api/v1/ports/{F}/registers/0x3040")
    assert mode.status_code == 200
    value = mode.json()["value"]
    assert mode.json()["fields"] == cam.sensor(F).fields_of("read_mode", value)


def test_health_reads_every_sensor_identity_the_lepton_by_its_cci_status(camera):
    _, cam = camera()
    report = cam.health()
    assert report["status"] == "ok"
    assert [p["ok"] for p in report["ports"]] == [True, True, True, True]
    assert cam.sensor(L).read_chip_id() == cci.STATUS_READY
    assert cam.info()["ports"][L]["sensor"]["chip_id"] == cci.STATUS_READY


# -- the simulated Lepton's CCI state machine ---------------------------------------------


def sim_lepton():
    bus = SimI2CBus("port 2")
    chip = SimLepton35()
    bus.attach(0x2A, chip)
    return chip, RegisterIO(bus, 0x2A, reg_bytes=2, bus_name="port 2")


def test_sim_lepton_is_busy_for_a_number_of_status_polls():
    chip, io = sim_lepton()
    chip.sim_busy_polls = 3
    io.write(cci.REG_DATA_LENGTH, 0)
    io.write(cci.REG_COMMAND, 0x0202)
    assert [io.read_word(cci.REG_STATUS) for _ in range(4)] == [0x7, 0x7, 0x7, 0x6]
    io.write(cci.REG_COMMAND, 0x0242)  # an FFC keeps it busy longer
    polls = 0
    while io.read_word(cci.REG_STATUS) & 1:
        polls += 1
    assert polls == chip.sim_ffc_polls and chip.ffc_count == 1


@pytest.mark.parametrize(
    ("length", "command", "code"),
    [
        (1, 0x0214, 0),  # FPA temperature: 1 word
        (2, 0x0214, -6),  # wrong data length
        (0, 0x0854, -7),  # OEM command without the protection bit
        (2, 0x02F0, -7),  # no such command
        (0, 0x0201, -7),  # ping cannot SET
    ],
)
def test_sim_lepton_error_codes(length, command, code):
    _, io = sim_lepton()
    io.write(cci.REG_DATA_LENGTH, length)
    io.write(cci.REG_COMMAND, command)
    while (status := io.read_word(cci.REG_STATUS)) & 1:
        pass
    assert cci.error_code(status) == code
    assert status & 0x6 == 0x6  # booted


def test_sim_lepton_range_error_on_a_bad_enum_and_reboot_wait():
    chip, io = sim_lepton()
    driver = Lepton35(io)
    with pytest.raises(LeptonError, match="range error") as info:
        driver.cci.set_value(cci.COMMANDS["OEM_GPIO_MODE"], 9)
    assert info.value.code == -3
    chip.sim_reboot(polls=3)
    assert io.read_word(cci.REG_STATUS) & 0x6 == 0  # booting
    driver.cci.wait_ready(booted=True)
    driver.ping()
    assert chip.attributes["OEM_GPIO_MODE"] == 0  # power-on value again
