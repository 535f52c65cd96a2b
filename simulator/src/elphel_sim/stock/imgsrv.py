"""imgsrv, the stock NC393's image server: one per sensor port, URL = a command sequence.

A request path is a sequence of commands separated by ``/`` (also ``?`` and ``&``), run
left to right and case sensitive; the frame pointer starts at the newest frame
(``last``). Pointers here are frame numbers:

- ``last`` the newest frame; ``towp`` where the next frame will land (newest + 1);
  ``prev`` / ``next`` one back / on (``next`` stops at the write pointer); ``first`` /
  ``second`` the oldest / second oldest in the ring buffer; ``save`` stores the pointer
  as the port's global read pointer, ``torp`` goes back to it (to ``second`` if that
  frame is gone); ``wait`` waits until the frame at the pointer is there.
- ``img``, ``bimg``, ``simg``, ``sbimg`` send the frame at the pointer (the ``s`` forms
  as an attachment); only the first output command counts. A frame that is not there
  (not taken yet, or overwritten) gives a 1x1 GIF, as the camera does.
- ``frame`` / ``wframe`` (only as the first command) answer the newest frame number
  as ten digits and CRLF, ``wframe`` after waiting for the next frame.
- ``trig`` fires one internal trigger (ports in snapshot mode take a frame).
- ``timestamp_name`` drops the ``elphelimg_`` prefix of the file name, ``bchn<n>``
  adds n to the channel in it; ``exif`` / ``noexif`` are accepted (frames always carry
  their Exif here).
- Anything else is ignored (the camera logs it); with no output command the answer is
  a 1x1 GIF. A bare ``/`` answers a plain-text summary of the commands.

Not modelled: multipart streams (``mimg``), ``pointers``, ``meta`` and byte offsets as
pointers; they are ignored like unknown commands.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import partial
from typing import Any

from PIL import Image

from elphel_camd.errors import FrameNotAvailableError
from elphel_sim.stock.compressor import EncodedFrame
from elphel_sim.stock.firmware import StockFirmware

HEADERS = {
    "Server": "Elphel Imgsrv",
    "Access-Control-Allow-Origin": "*",
    "Access-Control-Expose-Headers": "Content-Disposition",
}
IMAGE_HEADERS = {"Expires": "0", "Pragma": "no-cache"}
OUTPUTS = ("img", "bimg", "simg", "sbimg")
USAGE = (
    "elphel-sim imgsrv (a simulated NC393 image server, one per sensor port).\n"
    "Commands, separated by '/', run left to right:\n"
    "  img bimg simg sbimg   the frame at the pointer (JP4, JP46 or TIFF by COLOR)\n"
    "  frame wframe          the newest frame number (wframe: after the next frame)\n"
    "  last towp prev next first second save torp wait   move the frame pointer\n"
    "  trig                  one internal trigger (TRIG=4, TRIG_CONDITION=0)\n"
    "  timestamp_name bchn<n>   file name <sec>_<usec>_<channel>.<ext>\n"
)


def _gif_1x1() -> bytes:
    buf = io.BytesIO()
    Image.new("1", (1, 1), 1).save(buf, format="GIF")
    return buf.getvalue()


GIF_1X1 = _gif_1x1()


@dataclass(frozen=True)
class Reply:
    """An HTTP answer: status, headers (besides Content-Length) and body.

    With ``rest``, ``body`` is only the answer's first bytes (a frame's Exif head) and
    ``rest()`` gives the others (forming the frame's image: seconds for a full frame);
    ``release()`` lets go of the frame once the answer is done, sent or not.
    """

    body: bytes
    content_type: str
    headers: dict[str, str] = field(default_factory=dict)
    status: int = 200
    rest: Callable[[], bytes] | None = None
    release: Callable[[], None] | None = None


def gif() -> Reply:
    return Reply(GIF_1X1, "image/gif", dict(HEADERS))


class Imgsrv:
    """The image server of one sensor port.

    Parameters
    ----------
    firmware
        The simulated camera's firmware.
    port
        The sensor port this server serves.
    """

    def __init__(self, firmware: StockFirmware, port: int) -> None:
        self.firmware = firmware
        self.port = port

    def handle(self, path: str) -> Reply:
        """Answer one request path (everything after the host, e.g. ``/towp/wait/bimg``)."""
        fw, port = self.firmware, self.port
        commands = [c for c in path.lstrip("/").replace("?", "/").replace("&", "/").split("/")]
        if not any(commands):
            return Reply(USAGE.encode("ascii"), "text/plain", dict(HEADERS))
        first = commands[0]
        if first.startswith(("frame", "wframe")):
            if first.startswith("wframe"):
                fw.wait_frame(port, fw.frame(port) + 1)
            body = f"{fw.frame(port):010d}\r\n".encode("ascii")
            return Reply(body, "text/plain", dict(HEADERS))
        pointer = fw.frame(port)
        timestamp_name, base_chn = False, 0
        for command in commands:
            newest = fw.frame(port)
            if command in OUTPUTS:
                return self._image(pointer, command.startswith("s"), timestamp_name, base_chn)
            if command == "last":
                pointer = newest
            elif command == "towp":
                pointer = newest + 1
            elif command == "prev":
                pointer = max(pointer - 1, fw.oldest(port))
            elif command == "next":
                pointer = min(pointer + 1, newest + 1)
            elif command in ("first", "second"):
                pointer = fw.oldest(port) + (command == "second")
            elif command == "save":
                fw.read_pointers[port] = pointer
            elif command == "torp":
                saved = fw.read_pointers.get(port, 0)
                pointer = saved if fw.oldest(port) <= saved <= newest else fw.oldest(port) + 1
            elif command == "wait":
                fw.wait_frame(port, pointer)
            elif command == "trig":
                fw.trigger(port)
            elif command == "timestamp_name":
                timestamp_name = True
            elif command.startswith("bchn"):
                digits = command[4:]
                base_chn = int(digits) if digits.isdigit() else 0
        return gif()

    def _image(self, frame: int, save: bool, timestamp_name: bool, base_chn: int) -> Reply:
        """The frame's file: whole if encoded before, else its Exif head and the rest to come.

        As the camera copies a frame before sending it, the frame is held from its head
        on (`StockFirmware.hold`), so the rest comes even if it leaves the ring meanwhile.
        """
        fw, port = self.firmware, self.port
        name = partial(self._headers, save=save, timestamp_name=timestamp_name, base_chn=base_chn)
        if not fw.has_sensor(port) or not fw.oldest(port) <= frame <= fw.frame(port):
            return gif()  # not taken yet, or no longer in the buffer
        try:
            kept = fw.kept(port, frame)
            if kept is not None:
                return Reply(kept[0].data, kept[0].content_type, name(*kept))
            fw.hold(port, frame)
        except FrameNotAvailableError:
            return gif()
        held = True
        try:
            head = fw.head(port, frame)
            if head is None:  # a raw frame: sent whole
                encoded, metadata = fw.encoded(port, frame)
                return Reply(encoded.data, encoded.content_type, name(encoded, metadata))
            held = False  # the reply lets go of it
            data = head[0].data
            rest, release = partial(self._rest, frame, data), partial(fw.release, port, frame)
            return Reply(data, head[0].content_type, name(*head), rest=rest, release=release)
        finally:
            if held:
                fw.release(port, frame)

    def _headers(
        self,
        encoded: EncodedFrame,
        metadata: Mapping[str, Any],
        *,
        save: bool,
        timestamp_name: bool,
        base_chn: int,
    ) -> dict[str, str]:
        """A frame's headers: its file name from its time, port and format."""
        ns = int(metadata["timestamp_ns"])
        sec, usec = ns // 1_000_000_000, (ns // 1000) % 1_000_000
        prefix = "" if timestamp_name else "elphelimg_"
        name = f"{prefix}{sec}_{usec:06d}_{self.port + base_chn}.{encoded.extension}"
        disposition = f'{"attachment" if save else "inline"}; filename="{name}"'
        return {**HEADERS, **IMAGE_HEADERS, "Content-Disposition": disposition}

    def _rest(self, frame: int, head: bytes) -> bytes:
        """What follows ``head`` in the (held) frame's file: the frame is formed and encoded."""
        encoded, _ = self.firmware.encoded(self.port, frame)
        if not encoded.data.startswith(head):
            raise RuntimeError(
                f"port {self.port} frame {frame}: the encoded file does not start with the "
                f"{len(head)}-byte Exif head sent before it"
            )
        return encoded.data[len(head) :]
