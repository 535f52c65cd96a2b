"""Frame-ahead changes on the v4l2 board: set at the frame the sequence counter names, and
each frame's metadata the values the driver applied to it, rounded as the driver rounds.

The synthetic node rounds the analogue gain to steps of 5 codes and the exposure to
steps of 8 lines, and keeps, by sequence number, the control values each frame was taken
with: the truth every frame's metadata is compared with.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest

from elphel_camd.boards.v4l2 import V4L2Board, V4L2Port
from elphel_camd.service import CameraService
from elphel_camd.v4l2.controls import CID_ANALOGUE_GAIN, CID_DIGITAL_GAIN, CID_EXPOSURE
from elphel_camd.v4l2.synthetic import SyntheticSource

FPS = 25.0
WIDTH = 16
LINE_US = (WIDTH + 168) / 182.4e6 * 1e6  # the synthetic IMX219's line: HBLANK 168, 182.4 MHz
UNITY = 0x10000
QUANTUM = {CID_ANALOGUE_GAIN: 5, CID_EXPOSURE: 8}


def gain_16(analogue_code: int, digital: int) -> int:
    """The gain (16.16) an IMX219 applies with these control values."""
    return round(256 / (256 - analogue_code) * digital / 256 * UNITY)


Rig = tuple[CameraService, SyntheticSource]


def dropped(service: CameraService) -> int:
    board = service.board
    assert isinstance(board, V4L2Board)
    return int(board.port_status(0)["dropped"])


def make_rig(before_sequencer: Callable[[int, int, int], None] | None = None) -> Rig:
    made: list[SyntheticSource] = []

    def node(port: V4L2Port) -> SyntheticSource:
        image = np.arange(8 * WIDTH, dtype=np.uint16).reshape(8, WIDTH)
        made.append(SyntheticSource(image, fps=FPS, path=port.video, quantum=QUANTUM))
        return made[-1]

    board = V4L2Board(["/dev/video0"], open_source=node, ring_frames=64)
    if before_sequencer is not None:  # runs at each frame before the sequencer programs
        board.on_frame_sync(before_sequencer)
    return CameraService(board), made[0]


@pytest.fixture
def rig() -> Iterator[Rig]:
    service, node = make_rig()
    yield service, node
    service.close()


def truth(node: SyntheticSource, frame: int) -> dict[str, int]:
    """The gain and exposure frame ``frame`` was taken with (frame 1 is sequence 0)."""
    values = node.applied[frame - 1]
    return {
        "GAING": gain_16(values[CID_ANALOGUE_GAIN], values[CID_DIGITAL_GAIN]),
        "VEXPOS": values[CID_EXPOSURE],
    }


def metadata(service: CameraService, frames: range) -> dict[int, dict[str, Any]]:
    return {f: service.capture(0, frame=f)[1] for f in frames}


# gain 4.0 (analogue code 192) and 101 lines; the driver rounds them to 190 and 104
CHANGES = {"GAING": 4 * UNITY, "EXPOS": round(101 * LINE_US)}


def test_a_change_lands_at_the_frame_named_with_the_values_the_driver_rounded_to(
    rig: Rig,
) -> None:
    service, node = rig
    target = service.capture(0)[0].frame + 4
    assert service.set_params(0, CHANGES, frame=target) == target
    seen = metadata(service, range(target - 2, target + 3))
    assert dropped(service) == 0  # so frame - 1 is the sequence
    old, new = truth(node, target - 1), truth(node, target)
    assert old == {"GAING": UNITY, "VEXPOS": 1600}  # the driver's defaults
    assert new == {"GAING": gain_16(190, 256), "VEXPOS": 104}
    for frame, meta in seen.items():
        expected = old if frame < target else new
        assert {k: meta[k] for k in expected} == expected, frame
        assert meta["EXPOS"] == round(expected["VEXPOS"] * LINE_US)
    assert service.params(0, frame=target)["GAING"] == new["GAING"]


def test_a_change_issued_late_is_not_credited_to_the_frames_taken_before_it() -> None:
    late: list[int] = []

    def stall(port: int, frame: int, timestamp_ns: int) -> None:
        if frame in late:  # the stream thread falls 2.5 frames behind the driver here
            time.sleep(2.5 / FPS)

    service, node = make_rig(stall)
    try:
        target = service.capture(0)[0].frame + 4
        late.append(target - 1)  # the frame whose sync issues the change for the target
        service.set_params(0, CHANGES, frame=target)
        seen = metadata(service, range(target - 1, target + 5))
        assert dropped(service) == 0
        applied = [f for f in seen if truth(node, f)["VEXPOS"] == 104]
        assert applied and applied[0] > target  # the driver applied it late
        for frame, meta in seen.items():
            assert {k: meta[k] for k in ("GAING", "VEXPOS")} == truth(node, frame), frame
    finally:
        service.close()
