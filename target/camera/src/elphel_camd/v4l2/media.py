"""The media controller behind a V4L2 capture node: its sensor subdevice and that format.

On a board with a media controller (the Raspberry Pi's unicam and CFE since late 2021)
the video node only moves bytes: the sensor is a subdevice (/dev/v4l-subdevN) with its
own format and controls, and STREAMON fails unless the sensor's format matches the
node's. `open_sensor` finds, through /dev/mediaN's topology (MEDIA_IOC_G_TOPOLOGY), the
camera-sensor entity that feeds the node's entity over enabled data links;
`SensorSubdev.match` sets its source pad's format (VIDIOC_SUBDEV_S_FMT) to the node's
size and the media bus code of the node's pixel format. Pure ctypes and fcntl; facts
from the kernel's uapi headers linux/media.h, linux/v4l2-subdev.h and
linux/media-bus-format.h. Nodes without a media controller (vivid, USB) have no sensor
here and need none.
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import glob
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from elphel_camd.errors import VideoNodeError
from elphel_camd.v4l2.formats import RawFormat
from elphel_camd.v4l2.source import StreamFormat

# fcntl.ioctl(fd, request, buffer): the seam unit tests replace with a fake kernel.
Ioctl = Callable[[int, int, ctypes.Structure], object]
DevNum = tuple[int, int]  # (major, minor) of a character device

ENT_F_CAM_SENSOR = 0x00020001  # MEDIA_ENT_F_CAM_SENSOR
INTF_T_V4L_VIDEO = 0x200  # MEDIA_INTF_T_V4L_VIDEO
INTF_T_V4L_SUBDEV = 0x203  # MEDIA_INTF_T_V4L_SUBDEV
PAD_FL_SINK = 1
PAD_FL_SOURCE = 2
LNK_FL_ENABLED = 1
LNK_FL_LINK_TYPE = 0xF << 28
LNK_FL_DATA_LINK = 0 << 28
LNK_FL_INTERFACE_LINK = 1 << 28
SUBDEV_FORMAT_ACTIVE = 1
MAX_HOPS = 8  # entities between a video node and its sensor (unicam 0, CFE's CSI-2 1)

# Media bus codes (media-bus-format.h) by (Bayer order or None for mono, bits).
BUS_CODES: dict[tuple[str | None, int], tuple[str, int]] = {
    ("BGGR", 8): ("SBGGR8_1X8", 0x3001),
    ("GBRG", 8): ("SGBRG8_1X8", 0x3013),
    ("GRBG", 8): ("SGRBG8_1X8", 0x3002),
    ("RGGB", 8): ("SRGGB8_1X8", 0x3014),
    ("BGGR", 10): ("SBGGR10_1X10", 0x3007),
    ("GBRG", 10): ("SGBRG10_1X10", 0x300E),
    ("GRBG", 10): ("SGRBG10_1X10", 0x300A),
    ("RGGB", 10): ("SRGGB10_1X10", 0x300F),
    ("BGGR", 12): ("SBGGR12_1X12", 0x3008),
    ("GBRG", 12): ("SGBRG12_1X12", 0x3010),
    ("GRBG", 12): ("SGRBG12_1X12", 0x3011),
    ("RGGB", 12): ("SRGGB12_1X12", 0x3012),
    ("BGGR", 16): ("SBGGR16_1X16", 0x301D),
    ("GBRG", 16): ("SGBRG16_1X16", 0x301E),
    ("GRBG", 16): ("SGRBG16_1X16", 0x301F),
    ("RGGB", 16): ("SRGGB16_1X16", 0x3020),
    (None, 8): ("Y8_1X8", 0x2001),
    (None, 10): ("Y10_1X10", 0x200A),
    (None, 12): ("Y12_1X12", 0x2013),
}
BUS_NAMES = {code: name for name, code in BUS_CODES.values()}
BUS_KINDS = {code: kind for kind, (_, code) in BUS_CODES.items()}


class _Packed(ctypes.Structure):
    _pack_ = 1


class DeviceInfo(_Packed):
    _fields_ = [
        ("driver", ctypes.c_char * 16),
        ("model", ctypes.c_char * 32),
        ("serial", ctypes.c_char * 40),
        ("bus_info", ctypes.c_char * 32),
        ("media_version", ctypes.c_uint32),
        ("hw_revision", ctypes.c_uint32),
        ("driver_version", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32 * 31),
    ]


class V2Entity(_Packed):
    _fields_ = [
        ("id", ctypes.c_uint32),
        ("name", ctypes.c_char * 64),
        ("function", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32 * 5),
    ]


class V2Interface(_Packed):
    _fields_ = [
        ("id", ctypes.c_uint32),
        ("intf_type", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32 * 9),
        ("major", ctypes.c_uint32),
        ("minor", ctypes.c_uint32),
        ("raw", ctypes.c_uint32 * 14),
    ]


class V2Pad(_Packed):
    _fields_ = [
        ("id", ctypes.c_uint32),
        ("entity_id", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("index", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32 * 4),
    ]


class V2Link(_Packed):
    _fields_ = [
        ("id", ctypes.c_uint32),
        ("source_id", ctypes.c_uint32),
        ("sink_id", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32 * 6),
    ]


class V2Topology(_Packed):
    _fields_ = [
        ("topology_version", ctypes.c_uint64),
        ("num_entities", ctypes.c_uint32),
        ("reserved1", ctypes.c_uint32),
        ("ptr_entities", ctypes.c_uint64),
        ("num_interfaces", ctypes.c_uint32),
        ("reserved2", ctypes.c_uint32),
        ("ptr_interfaces", ctypes.c_uint64),
        ("num_pads", ctypes.c_uint32),
        ("reserved3", ctypes.c_uint32),
        ("ptr_pads", ctypes.c_uint64),
        ("num_links", ctypes.c_uint32),
        ("reserved4", ctypes.c_uint32),
        ("ptr_links", ctypes.c_uint64),
    ]


class MbusFormat(ctypes.Structure):
    _fields_ = [
        ("width", ctypes.c_uint32),
        ("height", ctypes.c_uint32),
        ("code", ctypes.c_uint32),
        ("field", ctypes.c_uint32),
        ("colorspace", ctypes.c_uint32),
        ("ycbcr_enc", ctypes.c_uint16),
        ("quantization", ctypes.c_uint16),
        ("xfer_func", ctypes.c_uint16),
        ("flags", ctypes.c_uint16),
        ("reserved", ctypes.c_uint16 * 10),
    ]


class SubdevFormat(ctypes.Structure):
    _fields_ = [
        ("which", ctypes.c_uint32),
        ("pad", ctypes.c_uint32),
        ("format", MbusFormat),
        ("stream", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32 * 7),
    ]


def _iowr(kind: str, number: int, struct: type[ctypes.Structure]) -> int:
    return (3 << 30) | (ctypes.sizeof(struct) << 16) | (ord(kind) << 8) | number


MEDIA_IOC_DEVICE_INFO = _iowr("|", 0x00, DeviceInfo)
MEDIA_IOC_G_TOPOLOGY = _iowr("|", 0x04, V2Topology)
VIDIOC_SUBDEV_G_FMT = _iowr("V", 4, SubdevFormat)
VIDIOC_SUBDEV_S_FMT = _iowr("V", 5, SubdevFormat)


def bus_code(fmt: RawFormat) -> tuple[str, int]:
    """The media bus code (name, value) a sensor sends a raw pixel format's pixels in.

    Packed and unpacked forms of one format share a code (RAW10 either way is
    ``SRGGB10_1X10`` for RGGB): the receiver packs or not.
    """
    try:
        return BUS_CODES[(fmt.bayer, fmt.bits)]
    except KeyError:
        kind = fmt.bayer or "mono"
        known = ", ".join(name for name, _ in BUS_CODES.values())
        raise VideoNodeError(
            f"format {fmt.fourcc!r} ({kind}, {fmt.bits} bits) has no media bus code here; "
            f"known: {known}"
        ) from None


# -- topology -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Topology:
    """A media device's graph: entities, interfaces (device nodes), pads and links."""

    entities: dict[int, tuple[str, int]]  # id -> (name, function)
    interfaces: dict[int, tuple[int, DevNum]]  # id -> (type, (major, minor))
    pads: dict[int, tuple[int, int, int]]  # id -> (entity id, flags, index)
    links: tuple[tuple[int, int, int], ...]  # (source id, sink id, flags)

    def entity_of(self, kind: int, devnum: DevNum) -> int | None:
        """The entity behind a device node of an interface type, or None."""
        for intf_id, (intf_type, num) in self.interfaces.items():
            if intf_type == kind and num == devnum:
                for source, sink, flags in self.links:
                    if flags & LNK_FL_LINK_TYPE == LNK_FL_INTERFACE_LINK and source == intf_id:
                        return sink
        return None

    def devnode_of(self, entity: int, kind: int) -> DevNum | None:
        """The device number of an entity's interface of a type, or None."""
        for source, sink, flags in self.links:
            if flags & LNK_FL_LINK_TYPE == LNK_FL_INTERFACE_LINK and sink == entity:
                intf_type, devnum = self.interfaces.get(source, (0, (0, 0)))
                if intf_type == kind:
                    return devnum
        return None

    def upstream(self, entity: int) -> tuple[int, int] | None:
        """(entity, source pad index) feeding an entity over an enabled data link."""
        for source, sink, flags in self.links:
            if flags & LNK_FL_LINK_TYPE != LNK_FL_DATA_LINK or not flags & LNK_FL_ENABLED:
                continue
            sink_pad, source_pad = self.pads.get(sink), self.pads.get(source)
            if sink_pad is None or source_pad is None or sink_pad[0] != entity:
                continue
            return source_pad[0], source_pad[2]
        return None

    def sensor_of(self, video: DevNum) -> tuple[int, int] | None:
        """(sensor entity, its source pad index) feeding a video node, or None."""
        entity = self.entity_of(INTF_T_V4L_VIDEO, video)
        for _ in range(MAX_HOPS):
            if entity is None:
                return None
            found = self.upstream(entity)
            if found is None:
                return None
            entity, pad = found
            if self.entities.get(entity, ("", 0))[1] == ENT_F_CAM_SENSOR:
                return entity, pad
        return None


def _array(struct: type[ctypes.Structure], count: int) -> ctypes.Array[ctypes.Structure]:
    return (struct * max(count, 1))()


def read_topology(fd: int, ioctl: Ioctl = fcntl.ioctl) -> Topology:
    """A media device's topology (MEDIA_IOC_G_TOPOLOGY, counts first, then the arrays)."""
    for _ in range(5):  # the graph may change between the two calls: ask again
        counts = V2Topology()
        ioctl(fd, MEDIA_IOC_G_TOPOLOGY, counts)
        top = V2Topology(topology_version=counts.topology_version)
        arrays = {}
        for name, struct in (
            ("entities", V2Entity),
            ("interfaces", V2Interface),
            ("pads", V2Pad),
            ("links", V2Link),
        ):
            count = getattr(counts, f"num_{name}")
            arrays[name] = _array(struct, count)
            setattr(top, f"num_{name}", count)
            setattr(top, f"ptr_{name}", ctypes.addressof(arrays[name]))
        ioctl(fd, MEDIA_IOC_G_TOPOLOGY, top)
        if top.topology_version == counts.topology_version:
            return _topology(top, arrays)
    raise VideoNodeError("the media graph kept changing while it was read")


def _topology(top: V2Topology, arrays: dict[str, ctypes.Array[ctypes.Structure]]) -> Topology:
    def items(name: str) -> list[ctypes.Structure]:
        return list(arrays[name][: getattr(top, f"num_{name}")])

    return Topology(
        entities={e.id: (e.name.decode(errors="replace"), e.function) for e in items("entities")},
        interfaces={i.id: (i.intf_type, (i.major, i.minor)) for i in items("interfaces")},
        pads={p.id: (p.entity_id, p.flags, p.index) for p in items("pads")},
        links=tuple((k.source_id, k.sink_id, k.flags) for k in items("links")),
    )


def read_driver(fd: int, ioctl: Ioctl = fcntl.ioctl) -> str:
    """The media device's driver name (MEDIA_IOC_DEVICE_INFO), e.g. ``unicam``."""
    info = DeviceInfo()
    ioctl(fd, MEDIA_IOC_DEVICE_INFO, info)
    return info.driver.decode(errors="replace")


# -- the sensor subdevice -------------------------------------------------------------------


def device_number(path: str) -> DevNum:
    """(major, minor) of a character device."""
    rdev = os.stat(path).st_rdev
    return os.major(rdev), os.minor(rdev)


@dataclass
class SensorSubdev:
    """The sensor subdevice feeding a video node, opened.

    Parameters
    ----------
    media
        The media device it was found through (``/dev/media0``).
    driver
        That media device's driver (``unicam``).
    name
        The sensor entity's name (``imx219 10-0010``): its first word is the kernel driver.
    path
        Its subdevice node (``/dev/v4l-subdev0``).
    pad
        Its source pad feeding the video node.
    fd
        The open subdevice node (controls are read and set through it).
    """

    media: str
    driver: str
    name: str
    path: str
    pad: int
    fd: int
    ioctl: Ioctl = fcntl.ioctl

    def media_ctl(self, fmt: StreamFormat) -> str:
        """The media-ctl command that sets this sensor's format to a stream format's."""
        bus = bus_code(fmt.format)[0]
        return (
            f"media-ctl -d {self.media} --set-v4l2 "
            f"\"'{self.name}':{self.pad}[fmt:{bus}/{fmt.width}x{fmt.height}]\""
        )

    def hint(self, fmt: StreamFormat) -> str:
        """The two ways to make the sensor's format match the node's."""
        model = self.name.split()[0] if self.name else "<sensor>"
        return (
            f"set it with {self.media_ctl(fmt)}, or load the camera overlay with "
            f"media-controller=0 (e.g. dtoverlay={model},media-controller=0) so the video "
            "node carries the format and the controls"
        )

    def get_format(self) -> tuple[int, int, int]:
        """The source pad's active (width, height, bus code)."""
        sf = SubdevFormat(which=SUBDEV_FORMAT_ACTIVE, pad=self.pad)
        self._call(VIDIOC_SUBDEV_G_FMT, sf, "reading the format")
        return sf.format.width, sf.format.height, sf.format.code

    def match(self, fmt: StreamFormat) -> str | None:
        """Set the source pad to the stream's size and bus code; return the Bayer order sent.

        A sensor whose flips decide its Bayer order (the IMX219) keeps the order of its
        flips: the answer is that order (None for mono), and the node must follow it.
        Raises VideoNodeError naming media-ctl and the overlay option when the sensor
        sets another size or bit depth.
        """
        want = (fmt.width, fmt.height, bus_code(fmt.format)[1])
        got = self.get_format()
        if got != want:
            sf = SubdevFormat(which=SUBDEV_FORMAT_ACTIVE, pad=self.pad)
            sf.format.width, sf.format.height, sf.format.code = want
            self._call(VIDIOC_SUBDEV_S_FMT, sf, "setting the format", fmt)
            got = (sf.format.width, sf.format.height, sf.format.code)
        kind = BUS_KINDS.get(got[2])
        mono = fmt.format.bayer is None
        if (
            got[:2] != want[:2]
            or kind is None
            or kind[1] != fmt.format.bits
            or mono != (kind[0] is None)
        ):
            raise VideoNodeError(
                f"{self.path} ({self.name}): asked for {_shape(want)} to match the video "
                f"node, the sensor driver set {_shape(got)}; {self.hint(fmt)}"
            )
        return kind[0]

    def _call(
        self, request: int, arg: ctypes.Structure, doing: str, fmt: StreamFormat | None = None
    ) -> None:
        try:
            self.ioctl(self.fd, request, arg)
        except OSError as e:
            how = f"; {self.hint(fmt)}" if fmt is not None else ""
            raise VideoNodeError(
                f"{self.path} ({self.name}): {doing} failed: {e.strerror}{how}"
            ) from e

    def close(self) -> None:
        os.close(self.fd)


def _shape(fmt: tuple[int, int, int]) -> str:
    width, height, code = fmt
    return f"{BUS_NAMES.get(code, hex(code))}/{width}x{height}"


def open_sensor(
    video: str,
    *,
    media_nodes: Sequence[str] | None = None,
    subdev_nodes: Sequence[str] | None = None,
    ioctl: Ioctl = fcntl.ioctl,
    devnum: Callable[[str], DevNum] = device_number,
) -> SensorSubdev | None:
    """The sensor subdevice feeding a video node, opened; None without a media controller.

    Raises VideoNodeError when a sensor is found but its subdevice node cannot be opened.
    """
    target = devnum(video)
    for media in sorted(glob.glob("/dev/media*")) if media_nodes is None else media_nodes:
        try:
            fd = os.open(media, os.O_RDWR)
        except OSError:
            continue  # not ours to read (permissions) or gone: no help with this node
        try:
            topology, driver = read_topology(fd, ioctl), read_driver(fd, ioctl)
        except OSError:
            continue
        finally:
            os.close(fd)
        found = topology.sensor_of(target)
        if found is not None:
            entity, pad = found
            subdevs = glob.glob("/dev/v4l-subdev*") if subdev_nodes is None else subdev_nodes
            return _open_subdev(media, driver, topology, entity, pad, subdevs, ioctl, devnum)
    return None


def _open_subdev(
    media: str,
    driver: str,
    topology: Topology,
    entity: int,
    pad: int,
    subdevs: Sequence[str],
    ioctl: Ioctl,
    devnum: Callable[[str], DevNum],
) -> SensorSubdev:
    name = topology.entities[entity][0]
    wanted = topology.devnode_of(entity, INTF_T_V4L_SUBDEV)
    path = next((p for p in sorted(subdevs) if wanted and _same(p, wanted, devnum)), None)
    if path is None:
        raise VideoNodeError(
            f"{media}: sensor {name!r} has no /dev/v4l-subdev node (device {wanted}); "
            "its driver exposes no subdevice API to user space: load the camera overlay "
            "with media-controller=0"
        )
    try:
        fd = os.open(path, os.O_RDWR)
    except OSError as e:
        extra = " (add the user to the video group)" if e.errno == errno.EACCES else ""
        raise VideoNodeError(f"{path} ({name}): cannot open: {e.strerror}{extra}") from e
    return SensorSubdev(media, driver, name, path, pad, fd, ioctl)


def _same(path: str, wanted: DevNum, devnum: Callable[[str], DevNum]) -> bool:
    try:
        return devnum(path) == wanted
    except OSError:
        return False
