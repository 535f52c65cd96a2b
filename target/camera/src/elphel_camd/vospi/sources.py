"""Where VoSPI bytes come from: a spidev device, or a file or FIFO read plainly.

`open_source` picks by what the path is: a character device is a spidev node, set up for
the Lepton (SPI mode 3, the clock, transfers fitted to spidev's ``bufsiz``); a regular
file or a FIFO is read with plain reads, so a recording replays. A spidev node is reached
through the small `SpiDevice` seam (`LinuxSpidev` on Linux, a simulated Lepton in tests).
"""

from __future__ import annotations

import errno
import fcntl
import os
import select
import stat
import struct
import time
from pathlib import Path
from typing import Protocol

from elphel_camd.vospi.errors import VoSPIError, VoSPISetupError
from elphel_camd.vospi.packets import PACKET_BYTES, PACKETS_PER_SEGMENT_TELEMETRY

SPI_MODE = 3  # CPOL 1, CPHA 1
SPI_MODE_BITS = 0x03
SPI_LSB_FIRST = 0x08
MAX_CLOCK_HZ = 20_000_000
# A Lepton 3 sends about 106 segments of 61 packets of 1312 bits a second: 8.5 Mbit/s.
MIN_CLOCK_HZ = 9_000_000
BUFSIZ_PARAMETER = Path("/sys/module/spidev/parameters/bufsiz")
BUFSIZ_DEFAULT = 4096  # spidev's own default
MAX_TRANSFER_PACKETS = PACKETS_PER_SEGMENT_TELEMETRY


def _ioc(direction: int, number: int, size: int) -> int:
    """A Linux ioctl request number of the spidev ('k') family."""
    return direction << 30 | size << 16 | ord("k") << 8 | number


SPI_IOC_WR_MODE = _ioc(1, 1, 1)
SPI_IOC_RD_MODE = _ioc(2, 1, 1)
SPI_IOC_WR_MAX_SPEED_HZ = _ioc(1, 4, 4)
SPI_IOC_RD_MAX_SPEED_HZ = _ioc(2, 4, 4)


class ByteSource(Protocol):
    """Bytes of a VoSPI stream, as `elphel_camd.vospi.reader.VoSPIReader` reads them.

    ``realigns_on_deselect``: after `deselect` the device starts on a packet boundary, so
    bytes read before it are stale. ``hunt_limit_bytes``: bytes to search for the packet
    alignment before resynchronising again (None: no limit).
    """

    path: str
    realigns_on_deselect: bool
    hunt_limit_bytes: int | None

    def read(self, timeout_s: float) -> bytes | None:
        """The next bytes; None when none came within ``timeout_s``, b"" at the end."""
        ...

    def deselect(self, seconds: float) -> None:
        """Deselect the device (/CS high, SCK idle) for ``seconds``."""
        ...

    def now_ns(self) -> int:
        """The source's clock (monotonic; virtual for a simulated Lepton)."""
        ...

    def close(self) -> None: ...


class SpiDevice(Protocol):
    """A spidev node as the spidev source uses it (the seam a simulated Lepton fills)."""

    path: str

    def set_mode(self, mode: int) -> None: ...

    def mode(self) -> int: ...

    def set_max_speed_hz(self, hz: int) -> None: ...

    def max_speed_hz(self) -> int: ...

    def read(self, size: int) -> bytes:
        """One transfer of ``size`` bytes clocked in with /CS asserted."""
        ...

    def idle(self, seconds: float) -> None:
        """/CS deasserted and SCK idle for ``seconds``."""
        ...

    def now_ns(self) -> int: ...

    def close(self) -> None: ...


def _open_error(path: str, e: OSError, what: str) -> VoSPIError:
    if isinstance(e, FileNotFoundError):
        hint = "no such device: enable SPI (on a Pi: dtparam=spi=on) and check ls /dev/spidev*"
    elif isinstance(e, PermissionError):
        hint = "permission denied: run as a member of the device's group (often spi) or root"
    else:
        hint = f"{e.strerror or e}"
    return VoSPIError(f"{path}: cannot open the Lepton's {what}: {hint}")


class LinuxSpidev:
    """A Linux spidev node (/dev/spidevB.C): mode and clock by ioctl, transfers by read."""

    def __init__(self, path: str) -> None:
        self.path = path
        try:
            self._fd = os.open(path, os.O_RDWR)
        except OSError as e:
            raise _open_error(path, e, "spidev device") from e

    def _ioctl(self, request: int, arg: bytes) -> bytes:
        try:
            return fcntl.ioctl(self._fd, request, arg)
        except OSError as e:
            if e.errno == errno.ENOTTY:
                raise VoSPIError(f"{self.path}: not a spidev device (ioctl refused)") from e
            raise VoSPISetupError(f"{self.path}: SPI setup refused: {e.strerror}") from e

    def set_mode(self, mode: int) -> None:
        self._ioctl(SPI_IOC_WR_MODE, struct.pack("=B", mode))

    def mode(self) -> int:
        return int(struct.unpack("=B", self._ioctl(SPI_IOC_RD_MODE, b"\0"))[0])

    def set_max_speed_hz(self, hz: int) -> None:
        self._ioctl(SPI_IOC_WR_MAX_SPEED_HZ, struct.pack("=I", hz))

    def max_speed_hz(self) -> int:
        return int(struct.unpack("=I", self._ioctl(SPI_IOC_RD_MAX_SPEED_HZ, b"\0" * 4))[0])

    def read(self, size: int) -> bytes:
        try:
            return os.read(self._fd, size)
        except OSError as e:
            if e.errno == errno.EMSGSIZE:
                raise VoSPISetupError(
                    f"{self.path}: a {size}-byte transfer is longer than spidev.bufsiz: "
                    "raise the spidev module parameter bufsiz"
                ) from e
            raise VoSPIError(f"{self.path}: SPI read failed: {e.strerror}") from e

    def idle(self, seconds: float) -> None:
        time.sleep(seconds)  # spidev raises /CS between transfers

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def close(self) -> None:
        os.close(self._fd)


def read_bufsiz(path: Path = BUFSIZ_PARAMETER) -> int:
    """The ``bufsiz`` module parameter of spidev (its default when the file is missing)."""
    try:
        return int(path.read_text().strip())
    except FileNotFoundError:
        return BUFSIZ_DEFAULT
    except (OSError, ValueError) as e:
        raise VoSPISetupError(f"{path}: cannot read spidev's bufsiz: {e}") from e


def transfer_bytes(bufsiz: int, *, path: str) -> int:
    """Bytes per transfer: whole packets within ``bufsiz``, at most one segment's worth."""
    packets = min(bufsiz // PACKET_BYTES, MAX_TRANSFER_PACKETS)
    if packets < 1:
        raise VoSPISetupError(
            f"{path}: spidev.bufsiz is {bufsiz} bytes, less than one {PACKET_BYTES}-byte "
            "VoSPI packet: raise the spidev module parameter bufsiz (e.g. spidev.bufsiz=65536 "
            "on the kernel command line, or 'options spidev bufsiz=65536' in /etc/modprobe.d)"
        )
    return packets * PACKET_BYTES


class SpidevSource:
    """VoSPI bytes from a spidev device set up for the Lepton.

    Parameters
    ----------
    device
        The spidev node.
    bufsiz
        spidev's ``bufsiz`` (`read_bufsiz`): the longest transfer.
    clock_hz
        SPI clock, 9..20 MHz.
    """

    realigns_on_deselect = True
    hunt_limit_bytes: int | None = 2 * PACKET_BYTES

    def __init__(self, device: SpiDevice, *, bufsiz: int, clock_hz: int = MAX_CLOCK_HZ) -> None:
        self.device = device
        self.path = device.path
        if not MIN_CLOCK_HZ <= clock_hz <= MAX_CLOCK_HZ:
            raise VoSPISetupError(
                f"{self.path}: SPI clock {clock_hz} Hz; allowed: {MIN_CLOCK_HZ}..{MAX_CLOCK_HZ} "
                "(a Lepton 3 sends 8.5 Mbit/s and runs up to 20 MHz)"
            )
        self.transfer_bytes = transfer_bytes(bufsiz, path=self.path)
        device.set_mode(SPI_MODE)
        mode = device.mode()
        if mode & (SPI_MODE_BITS | SPI_LSB_FIRST) != SPI_MODE:
            raise VoSPISetupError(
                f"{self.path}: SPI mode {mode & SPI_MODE_BITS}"
                f"{' LSB first' if mode & SPI_LSB_FIRST else ''} after asking for mode 3; the "
                "Lepton needs mode 3 (CPOL=1, CPHA=1, MSB first): check the SPI controller "
                "and its device-tree overlay"
            )
        device.set_max_speed_hz(clock_hz)
        self.clock_hz = device.max_speed_hz()
        if self.clock_hz > MAX_CLOCK_HZ:
            raise VoSPISetupError(
                f"{self.path}: SPI clock {self.clock_hz} Hz after asking for {clock_hz}; "
                f"allowed: up to {MAX_CLOCK_HZ}"
            )

    def read(self, timeout_s: float) -> bytes | None:
        return self.device.read(self.transfer_bytes)

    def deselect(self, seconds: float) -> None:
        self.device.idle(seconds)

    def now_ns(self) -> int:
        return self.device.now_ns()

    def close(self) -> None:
        self.device.close()


class FileSource:
    """VoSPI bytes from a regular file (a recording) or a FIFO, by plain reads.

    A file ends at its end; a FIFO waits for a writer and never ends.
    """

    realigns_on_deselect = False
    hunt_limit_bytes: int | None = None
    read_bytes = 64 * PACKET_BYTES

    def __init__(self, path: str) -> None:
        self.path = path
        try:
            self._fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
            self.fifo = stat.S_ISFIFO(os.fstat(self._fd).st_mode)
        except OSError as e:
            raise _open_error(path, e, "VoSPI file") from e

    def read(self, timeout_s: float) -> bytes | None:
        ready, _, _ = select.select([self._fd], [], [], max(timeout_s, 0.0))
        if not ready:
            return None
        try:
            data = os.read(self._fd, self.read_bytes)
        except BlockingIOError:
            return None
        except OSError as e:
            raise VoSPIError(f"{self.path}: read failed: {e.strerror}") from e
        if not data and self.fifo:
            time.sleep(min(max(timeout_s, 0.0), 0.05))  # no writer now; one may come
            return None
        return data

    def deselect(self, seconds: float) -> None:
        """A file has no device to deselect: the bytes go on as recorded."""

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def close(self) -> None:
        os.close(self._fd)


def open_source(
    path: str, *, clock_hz: int = MAX_CLOCK_HZ, bufsiz_path: Path = BUFSIZ_PARAMETER
) -> SpidevSource | FileSource:
    """The byte source of a path: a spidev node, or a regular file or FIFO."""
    try:
        mode = os.stat(path).st_mode
    except OSError as e:
        raise _open_error(path, e, "VoSPI device or file") from e
    if stat.S_ISCHR(mode):
        device = LinuxSpidev(path)
        try:
            return SpidevSource(device, bufsiz=read_bufsiz(bufsiz_path), clock_hz=clock_hz)
        except BaseException:
            device.close()
            raise
    if stat.S_ISREG(mode) or stat.S_ISFIFO(mode):
        return FileSource(path)
    raise VoSPIError(f"{path}: not a spidev device, a file or a FIFO")
