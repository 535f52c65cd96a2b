"""A kernel-driven sensor's window and binning through its driver's modes."""

from __future__ import annotations

import time

import numpy as np
import pytest

from elphel_camd.errors import ControlRefusedError
from elphel_camd.params import WINDOW
from elphel_camd.v4l2.sensor import V4L2Sensor
from elphel_camd.v4l2.shape import ShapeOptions, with_binned_modes
from elphel_camd.v4l2.synthetic import SyntheticSource

# The frame sizes of the mainline imx219 driver's modes.
IMX219_MODES = ((3280, 2464), (1920, 1080), (1640, 1232), (640, 480))
SHAPE = ("WOI_WIDTH", "WOI_HEIGHT", "BIN_HOR", "BIN_VERT")


@pytest.fixture(scope="module")
def imx219_node() -> SyntheticSource:
    image = np.arange(2464 * 3280, dtype=np.uint32).reshape(2464, 3280) % 1024
    return SyntheticSource(image.astype(np.uint16), fourcc="RG10", sizes=IMX219_MODES)


def _sensor(node: SyntheticSource, model: str) -> V4L2Sensor:
    return V4L2Sensor(lambda: node, model=model, period_s=lambda: 0.0, reshape=node.set_shape)


def _set(sensor: V4L2Sensor, **changes: int) -> dict[str, int]:
    state = sensor.normalize({**sensor.defaults(), **changes}, frozenset(changes))
    sensor.program(WINDOW, state)
    sensor.record(1, time.monotonic_ns())  # a frame taken after the change
    return sensor.actual_gains({"FRAME": 1})


def test_the_imx219_drivers_binned_modes_are_their_windows_binned_x2(
    imx219_node: SyntheticSource,
) -> None:
    sensor = _sensor(imx219_node, "imx219")
    assert set(SHAPE) <= sensor.writable and "WOI_LEFT" not in sensor.writable
    assert sensor.limits()["BIN_HOR"] == (1, 2)
    read = _set(sensor, BIN_HOR=2, BIN_VERT=2)  # the whole array, binned
    fmt = imx219_node.stream_format
    assert (fmt.width, fmt.height) == (1640, 1232)
    assert [read[n] for n in SHAPE] == [3280, 2464, 2, 2]
    read = _set(sensor, WOI_WIDTH=1280, WOI_HEIGHT=960, BIN_HOR=2, BIN_VERT=2)
    assert (imx219_node.stream_format.width, imx219_node.stream_format.height) == (640, 480)
    assert [read[n] for n in SHAPE] == [1280, 960, 2, 2]
    read = _set(sensor, WOI_WIDTH=1920, WOI_HEIGHT=1080, BIN_HOR=1, BIN_VERT=1)
    assert [read[n] for n in SHAPE] == [1920, 1080, 1, 1]
    with pytest.raises(ControlRefusedError, match=r"3280x2464 binned x2 \(1640x1232\)"):
        _set(sensor, WOI_WIDTH=1640, WOI_HEIGHT=1232, BIN_HOR=1, BIN_VERT=1)
    with pytest.raises(ControlRefusedError, match="BIN_HOR=2, BIN_VERT=1"):
        _set(sensor, WOI_WIDTH=3280, WOI_HEIGHT=2464, BIN_HOR=2, BIN_VERT=1)


def test_a_driver_not_known_to_bin_offers_its_modes_as_they_are() -> None:
    image = np.zeros((2464, 3280), np.uint16)
    node = SyntheticSource(image, fourcc="RG10", sizes=IMX219_MODES, controls=())
    sensor = _sensor(node, "vivid")
    assert "BIN_HOR" not in sensor.writable and {"WOI_WIDTH", "WOI_HEIGHT"} <= sensor.writable
    read = _set(sensor, WOI_WIDTH=1640, WOI_HEIGHT=1232)
    assert [read[n] for n in SHAPE] == [1640, 1232, 1, 1]
    assert sensor.limits()["BIN_HOR"] == (1, 1)


def test_binned_modes_are_only_those_the_node_offers() -> None:
    options = with_binned_modes(ShapeOptions(sizes=((3280, 2464), (640, 480))), "imx219 10-0010")
    assert options.binned == (((640, 480), 2),)
    assert options.windows() == [(3280, 2464, 1), (1280, 960, 2)]
