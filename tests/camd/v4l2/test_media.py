"""The media controller: a video node's sensor subdevice found in a synthetic topology,
its format set to the node's, and the answers when that cannot be done.

`FakeKernel` answers the media and subdevice ioctls on ctypes structures as the kernel
does (G_TOPOLOGY counts first, then fills the caller's arrays by address); its sensor
snaps a size to its nearest mode and sends the Bayer order of its flips, as the IMX219
driver does.
"""

from __future__ import annotations

import ctypes
import errno
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from elphel_camd.errors import VideoNodeError
from elphel_camd.v4l2 import media
from elphel_camd.v4l2.formats import raw_format
from elphel_camd.v4l2.source import StreamFormat

VIDEO, SUBDEV, MEDIA = (81, 0), (81, 2), (246, 0)
SENSOR_NAME = "imx219 10-0010"
DATA = media.LNK_FL_ENABLED | media.LNK_FL_DATA_LINK
INTERFACE = media.LNK_FL_ENABLED | media.LNK_FL_INTERFACE_LINK
IO_V4L = 0x00010001
VID_IF_BRIDGE = 0x00005002
MODES = [(3280, 2464), (1920, 1080), (1640, 1232), (640, 480)]
Graph = dict[str, list[tuple[int | str, ...]]]
FLIPPED_10 = {(0, 0): 0x300F, (1, 0): 0x300A, (0, 1): 0x300E, (1, 1): 0x3007}


def unicam() -> Graph:
    """A Pi's unicam graph: sensor pad -> video node's pad, an embedded-data node beside."""
    return {
        "entities": [(1, SENSOR_NAME, media.ENT_F_CAM_SENSOR), (3, "unicam-image", IO_V4L)],
        "pads": [(2, 1, media.PAD_FL_SOURCE, 0), (4, 3, media.PAD_FL_SINK, 0)],
        "links": [(2, 4, DATA | 2), (10, 3, INTERFACE), (11, 1, INTERFACE)],
        "interfaces": [
            (10, media.INTF_T_V4L_VIDEO, *VIDEO),
            (11, media.INTF_T_V4L_SUBDEV, *SUBDEV),
        ],
    }


def through_bridge() -> Graph:
    """A CFE-like graph: the sensor feeds a CSI-2 receiver's sink, its source pad 4 the node."""
    return {
        "entities": [
            (1, SENSOR_NAME, media.ENT_F_CAM_SENSOR),
            (5, "csi2", VID_IF_BRIDGE),
            (3, "rp1-cfe-csi2_ch0", IO_V4L),
        ],
        "pads": [
            (2, 1, media.PAD_FL_SOURCE, 0),
            (6, 5, media.PAD_FL_SINK, 0),
            (7, 5, media.PAD_FL_SOURCE, 4),
            (4, 3, media.PAD_FL_SINK, 0),
        ],
        "links": [(2, 6, DATA), (7, 4, DATA), (10, 3, INTERFACE), (11, 1, INTERFACE)],
        "interfaces": [
            (10, media.INTF_T_V4L_VIDEO, *VIDEO),
            (11, media.INTF_T_V4L_SUBDEV, *SUBDEV),
        ],
    }


def video_only() -> Graph:
    """vivid's graph: a video node with nothing upstream."""
    return {
        "entities": [(3, "vivid-000-vid-cap", IO_V4L)],
        "pads": [(4, 3, media.PAD_FL_SINK, 0)],
        "links": [(10, 3, INTERFACE)],
        "interfaces": [(10, media.INTF_T_V4L_VIDEO, *VIDEO)],
    }


class FakeKernel:
    """The ioctls of one media device and its sensor subdevice."""

    def __init__(self, graph: Graph, *, driver: str = "unicam") -> None:
        self.graph = graph
        self.driver = driver
        self.version = 7
        self.bump_once = False  # the graph changes between the count and the fill
        self.flips = (0, 0)
        self.fmt = (1640, 1232, 0x300F)
        self.set_calls: list[tuple[int, int, int]] = []
        self.refuse: int | None = None

    def __call__(self, fd: int, request: int, arg: ctypes.Structure) -> int:
        if request == media.MEDIA_IOC_DEVICE_INFO:
            arg.driver = self.driver.encode()
        elif request == media.MEDIA_IOC_G_TOPOLOGY:
            self._topology(arg)
        elif request == media.VIDIOC_SUBDEV_G_FMT:
            arg.format.width, arg.format.height, arg.format.code = self.fmt
        elif request == media.VIDIOC_SUBDEV_S_FMT:
            self._set_format(arg)
        else:
            raise OSError(errno.ENOTTY, "Inappropriate ioctl for device")
        return 0

    def _topology(self, top: ctypes.Structure) -> None:
        fill = top.ptr_entities != 0
        top.topology_version = self.version
        if fill and self.bump_once:
            self.bump_once, self.version = False, self.version + 1
            top.topology_version = self.version
        for name, struct, fields in (
            ("entities", media.V2Entity, ("id", "name", "function")),
            ("pads", media.V2Pad, ("id", "entity_id", "flags", "index")),
            ("links", media.V2Link, ("source_id", "sink_id", "flags")),
            ("interfaces", media.V2Interface, ("id", "intf_type", "major", "minor")),
        ):
            rows = self.graph[name]
            setattr(top, f"num_{name}", len(rows))
            if not fill:
                continue
            array = (struct * len(rows)).from_address(getattr(top, f"ptr_{name}"))
            for item, row in zip(array, rows, strict=True):
                for field, value in zip(fields, row, strict=True):
                    setattr(item, field, value.encode() if isinstance(value, str) else value)

    def _set_format(self, sf: ctypes.Structure) -> None:
        if self.refuse is not None:
            raise OSError(self.refuse, "Invalid argument")
        asked = (sf.format.width, sf.format.height, sf.format.code)
        self.set_calls.append(asked)
        w, h = min(MODES, key=lambda m: abs(m[0] - asked[0]) + abs(m[1] - asked[1]))
        self.fmt = (w, h, FLIPPED_10[self.flips])
        sf.format.width, sf.format.height, sf.format.code = self.fmt


Opened = tuple[media.SensorSubdev, "FakeKernel"]


@dataclass
class Devices:
    """Files standing for the device nodes, and their device numbers."""

    paths: dict[str, str]
    numbers: dict[str, tuple[int, int]]


@pytest.fixture
def devices(tmp_path: Path) -> Devices:
    names = ("video0", "media0", "v4l-subdev0", "v4l-subdev1")
    paths = {name: str(tmp_path / name) for name in names}
    for p in paths.values():
        Path(p).touch()
    numbers = dict(zip(paths.values(), [VIDEO, MEDIA, (81, 1), SUBDEV], strict=True))
    return Devices(paths, numbers)


def opened(
    devices: Devices,
    kernel: FakeKernel,
    *,
    media_nodes: list[str] | None = None,
    subdev_nodes: list[str] | None = None,
) -> media.SensorSubdev | None:
    paths = devices.paths
    devnum: Callable[[str], tuple[int, int]] = devices.numbers.__getitem__
    return media.open_sensor(
        paths["video0"],
        media_nodes=[paths["media0"]] if media_nodes is None else media_nodes,
        subdev_nodes=[paths["v4l-subdev0"], paths["v4l-subdev1"]]
        if subdev_nodes is None
        else subdev_nodes,
        ioctl=kernel,
        devnum=devnum,
    )


@pytest.fixture
def sensor(devices: Devices) -> Iterator[Opened]:
    kernel = FakeKernel(unicam())
    found = opened(devices, kernel)
    assert found is not None
    yield found, kernel
    found.close()


def stream(fourcc: str, width: int = 3280, height: int = 2464) -> StreamFormat:
    fmt = raw_format(fourcc)
    return StreamFormat(fmt, width, height, fmt.line_bytes(width))


def test_packed_and_unpacked_raw10_share_a_bus_code_and_an_unknown_one_lists_the_known() -> None:
    assert media.bus_code(raw_format("pRAA")) == ("SRGGB10_1X10", 0x300F)
    assert media.bus_code(raw_format("RG10")) == ("SRGGB10_1X10", 0x300F)
    assert media.bus_code(raw_format("pBAA")) == ("SBGGR10_1X10", 0x3007)
    assert media.bus_code(raw_format("Y10 ")) == ("Y10_1X10", 0x200A)
    with pytest.raises(VideoNodeError, match=r"'Y16 ' \(mono, 16 bits\) has no media bus code"):
        media.bus_code(raw_format("Y16 "))


def test_the_structures_have_the_kernels_sizes_and_ioctl_numbers() -> None:
    sizes = {s: ctypes.sizeof(s) for s in (media.V2Entity, media.V2Interface, media.V2Pad)}
    assert sizes == {media.V2Entity: 96, media.V2Interface: 112, media.V2Pad: 32}
    assert ctypes.sizeof(media.V2Link) == 40 and ctypes.sizeof(media.DeviceInfo) == 256
    assert media.MEDIA_IOC_G_TOPOLOGY == 0xC0487C04  # 72-byte topology, '|' 4
    assert media.VIDIOC_SUBDEV_S_FMT == 0xC0585605  # 88-byte subdev format, 'V' 5


@pytest.mark.parametrize(
    ("graph", "expected"),
    [(unicam, (1, 0)), (through_bridge, (1, 0)), (video_only, None)],
)
def test_the_sensor_is_found_upstream_of_the_video_node(
    graph: Callable[[], Graph], expected: tuple[int, int] | None
) -> None:
    topology = media.read_topology(-1, FakeKernel(graph()))
    assert topology.sensor_of(VIDEO) == expected
    assert topology.sensor_of((81, 9)) is None  # another node


def test_a_disabled_link_feeds_nothing() -> None:
    graph = unicam()
    graph["links"][0] = (2, 4, media.LNK_FL_DATA_LINK)
    assert media.read_topology(-1, FakeKernel(graph)).sensor_of(VIDEO) is None


def test_a_graph_that_changes_while_read_is_read_again() -> None:
    kernel = FakeKernel(unicam())
    kernel.bump_once = True
    topology = media.read_topology(-1, kernel)
    assert topology.entities[1] == (SENSOR_NAME, media.ENT_F_CAM_SENSOR)


def test_the_subdevice_node_is_matched_by_device_number(devices: Devices, sensor: Opened) -> None:
    found, _ = sensor
    assert found.path.endswith("v4l-subdev1") and found.name == SENSOR_NAME
    assert found.pad == 0 and found.driver == "unicam"
    assert found.media == devices.paths["media0"]


def test_without_a_media_device_there_is_no_sensor(devices: Devices) -> None:
    assert opened(devices, FakeKernel(unicam()), media_nodes=[]) is None
    assert opened(devices, FakeKernel(video_only())) is None


def test_a_sensor_without_a_subdevice_node_names_the_overlay_option(devices: Devices) -> None:
    with pytest.raises(
        VideoNodeError, match=r"'imx219 10-0010' has no /dev/v4l-subdev.*media-controller=0"
    ):
        opened(devices, FakeKernel(unicam()), subdev_nodes=[devices.paths["v4l-subdev0"]])


def test_the_sensor_takes_the_nodes_size_and_bus_code(sensor: Opened) -> None:
    found, kernel = sensor
    assert found.match(stream("pRAA")) == "RGGB"
    assert kernel.set_calls == [(3280, 2464, 0x300F)]
    assert found.get_format() == (3280, 2464, 0x300F)
    assert found.match(stream("RG10")) == "RGGB"  # already so: nothing set
    assert len(kernel.set_calls) == 1


def test_a_flipped_sensor_answers_the_order_of_its_flips(sensor: Opened) -> None:
    found, kernel = sensor
    kernel.flips = (1, 1)  # the Pi's rotation 180: both flips, BGGR
    assert found.match(stream("pRAA", 640, 480)) == "BGGR"


def test_a_size_the_sensor_has_no_mode_for_names_media_ctl_and_the_overlay(sensor: Opened) -> None:
    found, _ = sensor
    with pytest.raises(VideoNodeError) as err:
        found.match(stream("pRAA", 1000, 700))
    text = str(err.value)
    assert "the sensor driver set SRGGB10_1X10/640x480" in text
    assert "\"'imx219 10-0010':0[fmt:SRGGB10_1X10/1000x700]\"" in text
    assert "media-ctl -d " in text and "dtoverlay=imx219,media-controller=0" in text


def test_a_refused_format_names_media_ctl_and_the_overlay(sensor: Opened) -> None:
    found, kernel = sensor
    kernel.refuse = errno.EINVAL
    with pytest.raises(
        VideoNodeError,
        match=r"setting the format failed: Invalid argument; .*media-ctl.*media-controller=0",
    ):
        found.match(stream("pRAA"))
    kernel.refuse = None
    with pytest.raises(VideoNodeError, match=r"asked for SRGGB12_1X12/.* set SRGGB10_1X10/"):
        found.match(stream("pRCC"))  # 12 bits: this sensor sends 10
