"""Find stage boards: USB-UART bridges by vendor/product id and the port each provides.

pyusb is used when it is installed and has a backend (it sees bridges even when no
driver bound a tty); otherwise pyserial's port list, which also carries the ids.
"""

from __future__ import annotations

from dataclasses import dataclass

from serial.tools import list_ports

# USB-UART bridges found on ESP8266 boards (NodeMCU, Wemos D1 mini and clones).
BRIDGES: dict[tuple[int, int], str] = {
    (0x1A86, 0x7523): "WCH CH340",
    (0x1A86, 0x55D4): "WCH CH9102",
    (0x10C4, 0xEA60): "Silicon Labs CP210x",
    (0x0403, 0x6001): "FTDI FT232R",
    (0x0403, 0x6015): "FTDI FT231X",
    (0x067B, 0x2303): "Prolific PL2303",
}


@dataclass(frozen=True)
class StageBoard:
    vid: int
    pid: int
    bridge: str
    port: str | None  # serial device the bridge provides (None: no driver bound)
    serial_number: str | None
    location: str | None


def _from_pyserial() -> list[StageBoard]:
    boards = []
    for info in list_ports.comports():
        if info.vid is None or info.pid is None:
            continue
        name = BRIDGES.get((info.vid, info.pid))
        if name is not None:
            boards.append(
                StageBoard(info.vid, info.pid, name, info.device, info.serial_number, info.location)
            )
    return boards


def _from_pyusb() -> list[StageBoard] | None:
    try:
        import usb.core
    except ImportError:
        return None
    try:
        devices = list(usb.core.find(find_all=True))
    except Exception:  # pyusb raises NoBackendError (and others) without a libusb backend
        return None
    ports = {(b.vid, b.pid, b.location): b for b in _from_pyserial()}
    by_ids = {(b.vid, b.pid): b for b in ports.values()}
    boards = []
    for dev in devices:
        key = (int(dev.idVendor), int(dev.idProduct))
        name = BRIDGES.get(key)
        if name is None:
            continue
        path = ".".join(str(p) for p in (getattr(dev, "port_numbers", None) or ()))
        location = f"{dev.bus}-{path}" if path else None
        match = ports.get((*key, location)) or by_ids.get(key)
        boards.append(
            StageBoard(
                key[0],
                key[1],
                name,
                match.port if match else None,
                match.serial_number if match else None,
                location,
            )
        )
    return boards


def find_stage_boards() -> list[StageBoard]:
    """Connected USB-UART bridges of the kinds used on stage boards, with their ports."""
    found = _from_pyusb()
    return found if found is not None else _from_pyserial()
