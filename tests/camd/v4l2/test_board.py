"""The v4l2 board on synthetic nodes: frames, numbering, drops, faults, controls."""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from elphel_camd.boards.v4l2 import V4L2Board, V4L2Port
from elphel_camd.errors import (
    ConfigError,
    ControlRefusedError,
    DeviceBusyError,
    FrameNotAvailableError,
    PortDisconnectedError,
)
from elphel_camd.params import EXPOSURE, GAINS, WINDOW
from elphel_camd.service import CameraService
from elphel_camd.v4l2.controls import CID_ANALOGUE_GAIN, CID_DIGITAL_GAIN, CID_EXPOSURE
from elphel_camd.v4l2.synthetic import SyntheticSource

HEIGHT, WIDTH = 8, 16


def _image(seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 1024, (HEIGHT, WIDTH), dtype=np.uint16)


class Nodes:
    """Synthetic nodes by path; a vanished one is refused until it returns."""

    def __init__(self, **kwargs: Any) -> None:
        self.kwargs = kwargs
        self.made: dict[str, SyntheticSource] = {}
        self.gone: set[str] = set()

    def __call__(self, port: V4L2Port) -> SyntheticSource:
        if port.video in self.gone:
            raise PortDisconnectedError(f"{port.video}: no such node")
        source = SyntheticSource(_image(), path=port.video, **self.kwargs)
        self.made[port.video] = source
        return source


@pytest.fixture
def nodes() -> Nodes:
    return Nodes(fourcc="pRAA", fps=200.0, pad=4)


@pytest.fixture
def board(nodes: Nodes) -> Iterator[V4L2Board]:
    b = V4L2Board(["/dev/video0"], open_source=nodes, ring_frames=16)
    events: list[tuple[str, dict[str, Any]]] = []
    b.on_event(lambda kind, payload: events.append((kind, payload)))
    b.events = events  # type: ignore[attr-defined]
    yield b
    b.close()


def test_the_next_frame_is_the_packed_image_with_its_number_and_time(board: V4L2Board) -> None:
    got = board.capture(0)
    np.testing.assert_array_equal(got.image, _image())
    assert got.frame >= 1 and got.timestamp_ns > 0
    later = board.capture(0)
    assert later.frame > got.frame and later.timestamp_ns > got.timestamp_ns


def test_a_recent_frame_comes_from_the_ring_and_an_old_one_is_gone(board: V4L2Board) -> None:
    first = board.capture(0)
    while board.streams[0].last_frame < first.frame + 20:
        time.sleep(0.01)
    with pytest.raises(FrameNotAvailableError, match=f"frame {first.frame} is not in the ring"):
        board.capture(0, frame=first.frame)
    recent = board.streams[0].last_frame - 2
    assert board.capture(0, frame=recent).frame == recent


def test_frame_syncs_follow_the_sequence_and_a_gap_is_counted_as_drops(
    board: V4L2Board, nodes: Nodes
) -> None:
    seen: list[int] = []
    board.on_frame_sync(lambda port, frame, ts: seen.append(frame))
    before = board.capture(0).frame
    nodes.made["/dev/video0"].sim_drop(5)
    while board.streams[0].last_frame < before + 10:
        time.sleep(0.01)
    assert board.port_status(0)["dropped"] >= 5
    drops = [p for k, p in board.events if p.get("error") == "frames_dropped"]  # type: ignore[attr-defined]
    assert any(p["frames"] == 5 for p in drops)
    gap = [b - a for a, b in itertools.pairwise(seen) if b - a > 1]
    assert 6 in gap  # five frames skipped between two syncs


def test_a_vanished_node_disconnects_the_port_and_it_recovers(
    board: V4L2Board, nodes: Nodes
) -> None:
    board.capture(0)
    nodes.gone.add("/dev/video0")
    nodes.made["/dev/video0"].sim_gone = True
    deadline = time.monotonic() + 5
    while board.port_status(0)["state"] != "disconnected" and time.monotonic() < deadline:
        time.sleep(0.01)
    assert board.port_status(0)["state"] == "disconnected"
    with pytest.raises(PortDisconnectedError, match="/dev/video0 is disconnected"):
        board.capture(0)
    states = [p["state"] for k, p in board.events if k == "port"]  # type: ignore[attr-defined]
    assert "disconnected" in states
    last = board.streams[0].last_frame
    nodes.gone.clear()
    while board.port_status(0)["state"] != "streaming" and time.monotonic() < deadline + 5:
        time.sleep(0.01)
    got = board.capture(0, timeout_s=5)
    assert got.frame > last  # numbering goes on after the node returned
    assert board.port_status(0)["state"] == "streaming"
    assert board.port_status(0)["restarts"] == 1


def test_a_streaming_error_restarts_the_stream_and_is_reported(
    board: V4L2Board, nodes: Nodes
) -> None:
    first = board.capture(0).frame
    nodes.made["/dev/video0"].sim_streaming_error()
    assert board.capture(0, timeout_s=5).frame > first
    errors = [p for k, p in board.events if k == "error"]  # type: ignore[attr-defined]
    assert any("streaming failed" in p["detail"] for p in errors)


def test_silence_for_several_periods_is_a_timeout_naming_them(
    board: V4L2Board, nodes: Nodes
) -> None:
    board.capture(0)
    board.capture(0)
    nodes.made["/dev/video0"].sim_silent = True
    start = time.monotonic()
    with pytest.raises(
        TimeoutError, match=r"no frame from /dev/video0 .*5 frame periods of 5\.0 ms"
    ):
        board.capture(0, timeout_s=10)
    assert time.monotonic() - start < 2  # 5 periods of 5 ms (at least 0.2 s), not 10 s


def test_a_busy_node_is_refused_at_start() -> None:
    def busy(port: V4L2Port) -> SyntheticSource:
        source = SyntheticSource(_image(), path=port.video)
        source.sim_busy = True
        return source

    with pytest.raises(DeviceBusyError, match="another program is streaming"):
        V4L2Board(["/dev/video0"], open_source=busy)


def test_controls_carry_exposure_gain_and_flips_and_the_bayer_order_follows(
    board: V4L2Board, nodes: Nodes
) -> None:
    sensor = board.sensors()[0]
    assert sensor.writable == {"EXPOS", "GAINR", "GAING", "GAINGB", "GAINB", "FLIPH", "FLIPV"}
    assert sensor.bayer == "RGGB"
    state = sensor.defaults()
    # 1600 lines of (3280 + 168) px at 182.4 MHz: 30.25 ms
    line_s = (WIDTH + 168) / 182.4e6
    assert state["EXPOS"] == round(1600 * line_s * 1e6)
    state.update(EXPOS=round(100 * line_s * 1e6), FLIPH=1, FLIPV=1)
    state.update(dict.fromkeys(("GAINR", "GAING", "GAINGB", "GAINB"), 4 * 0x10000))
    for fn in (WINDOW, GAINS, EXPOSURE):
        sensor.program(fn, sensor.normalize(state, frozenset(state)))
    node = nodes.made["/dev/video0"]
    values = node.get_controls([CID_EXPOSURE, CID_ANALOGUE_GAIN, CID_DIGITAL_GAIN])
    assert values[CID_EXPOSURE] == 100
    assert values[CID_ANALOGUE_GAIN] == 192  # 256 / (256 - 192) = 4.0, all analogue
    assert values[CID_DIGITAL_GAIN] == 256
    assert node.stream_format.format.fourcc == "pBAA"  # RGGB mirrored both ways
    assert sensor.bayer == "RGGB"  # the metadata flips it again


def test_frames_record_the_values_read_back_from_the_driver(board: V4L2Board, nodes: Nodes) -> None:
    sensor = board.sensors()[0]
    nodes.made["/dev/video0"].set_controls({CID_ANALOGUE_GAIN: 128})  # 2.0, set behind our back
    seen = board.capture(0).frame  # the change is read back when this frame arrives
    board.capture(0, frame=seen + 2)  # so it has been read back by now
    # and counts from the frames taken after that: take one begun after now
    now_ns = time.monotonic_ns()
    later = board.capture(0)
    while later.timestamp_ns <= now_ns:
        later = board.capture(0)
    read = sensor.actual_gains({"FRAME": later.frame})
    assert read["GAING"] == 2 * 0x10000 and read["FLIPH"] == 0


def test_a_value_beyond_the_drivers_limits_is_refused_naming_them(board: V4L2Board) -> None:
    sensor = board.sensors()[0]
    state = sensor.defaults()
    state["EXPOS"] = 10_000_000  # 10 s: more lines than the driver allows
    with pytest.raises(ControlRefusedError, match=r"'Exposure' takes 4\.\.3522 step 1"):
        sensor.normalize(state, frozenset({"EXPOS"}))
    state = sensor.defaults()
    state.update(GAINR=0x20000, GAING=0x30000)
    with pytest.raises(ControlRefusedError, match="one gain for all colours"):
        sensor.normalize(state, frozenset({"GAINR", "GAING"}))


def test_two_nodes_stream_side_by_side(nodes: Nodes) -> None:
    board = V4L2Board(["/dev/video0", "/dev/video1"], open_source=nodes)
    try:
        results: dict[int, int] = {}
        threads = [
            threading.Thread(target=lambda p=p: results.update({p: board.capture(p).frame}))
            for p in (0, 1)
        ]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert set(results) == {0, 1}
    finally:
        board.close()


def test_limits_come_from_the_drivers_controls(board: V4L2Board) -> None:
    limits = board.sensors()[0].limits()
    line_s = (WIDTH + 168) / 182.4e6
    assert limits["EXPOS"] == (round(4 * line_s * 1e6), round(3522 * line_s * 1e6))
    # analogue 256 / (256 - 232) = 10.67 times digital 4095 / 256 = 16.0
    assert limits["GAING"] == (0x10000, round(256 / 24 * 4095 / 256 * 0x10000))
    assert limits["WOI_WIDTH"] == (WIDTH, WIDTH)


def test_a_size_that_is_not_width_x_height_is_refused() -> None:
    with pytest.raises(ConfigError, match="size '640'; allowed: WIDTHxHEIGHT"):
        V4L2Port("/dev/video0", size="640").size_tuple()
    assert V4L2Port("/dev/video0", size="640x480").size_tuple() == (640, 480)


def test_a_board_without_nodes_is_refused() -> None:
    with pytest.raises(ConfigError, match="needs at least one node"):
        V4L2Board([])


def test_a_frame_that_cannot_be_taken_restarts_the_stream_instead_of_ending_it(
    board: V4L2Board, nodes: Nodes
) -> None:
    first = board.capture(0).frame
    node = nodes.made["/dev/video0"]
    full = node.data
    node.data = full[:10]  # a short buffer: fewer bytes than the format's lines
    deadline = time.monotonic() + 5
    while board.port_status(0)["restarts"] < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    node.data = full
    assert board.port_status(0)["restarts"] >= 1
    assert board.capture(0, timeout_s=5).frame > first
    errors = [p["detail"] for k, p in board.events if k == "error"]  # type: ignore[attr-defined]
    assert any("could not be taken" in d for d in errors)


def test_a_shape_the_driver_refuses_keeps_the_old_one_streaming_and_is_asked_once() -> None:
    nodes = Nodes(fourcc="RG10", fps=200.0, sizes=((WIDTH, HEIGHT), (8, 4)))
    b = V4L2Board(["/dev/video0"], open_source=nodes, ring_frames=16)
    asked: list[Any] = []

    def refuse(shape: Any) -> Any:
        asked.append(shape)
        raise ControlRefusedError("size", shape.size, "not today (the driver)")

    try:
        b.capture(0)
        nodes.made["/dev/video0"].set_shape = refuse  # type: ignore[method-assign]
        sensor = b.sensors()[0]
        state = sensor.normalize(
            {**sensor.defaults(), "WOI_WIDTH": 8, "WOI_HEIGHT": 4},
            frozenset({"WOI_WIDTH", "WOI_HEIGHT"}),
        )
        with pytest.raises(ControlRefusedError, match="a window the driver of /dev/video0 takes"):
            sensor.program(WINDOW, state)
        assert "WOI_WIDTH" not in sensor.program(WINDOW, state) and len(asked) == 1
        got = b.capture(0)
        assert got.image.shape == (HEIGHT, WIDTH)
        assert b.port_status(0)["state"] == "streaming"
    finally:
        b.close()


def test_the_next_frame_after_lost_ones_is_the_next_delivered(
    board: V4L2Board, nodes: Nodes
) -> None:
    board.capture(0)
    node = nodes.made["/dev/video0"]
    node.sim_silent = True
    time.sleep(0.1)
    last = board.streams[0].last_frame
    node.sim_drop(3)
    got: list[Any] = []
    waiter = threading.Thread(target=lambda: got.append(board.capture(0, timeout_s=5)))
    waiter.start()
    time.sleep(0.1)
    node.sim_silent = False
    waiter.join(10)
    assert got and got[0].frame == last + 4  # frames last+1..last+3 were lost


def test_a_window_due_after_a_lost_frame_still_starts_at_the_frame_it_names() -> None:
    nodes = Nodes(fourcc="RG10", fps=50.0, crop=True)
    service = CameraService(V4L2Board(["/dev/video0"], open_source=nodes, ring_frames=16))
    try:
        service.capture(0)
        node = nodes.made["/dev/video0"]
        node.sim_silent = True
        time.sleep(0.1)
        target = service.set_params(0, {"WOI_WIDTH": 8, "WOI_HEIGHT": 4})
        node.sim_drop(1)  # the frame before the target is lost
        node.sim_silent = False
        got, meta = service.capture(0, frame=target)
        assert got.image.shape == (4, 8) and (meta["WOI_WIDTH"], meta["WOI_HEIGHT"]) == (8, 4)
        np.testing.assert_array_equal(got.image, _image()[:4, :8])
        with pytest.raises(FrameNotAvailableError, match=f"frame {target - 1} is not in"):
            service.capture(0, frame=target - 1)
    finally:
        service.close()
