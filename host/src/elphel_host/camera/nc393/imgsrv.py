"""imgsrv on the wire: the command paths a host needs and how their answers read.

One imgsrv per sensor port (BASE..BASE+3). A path is a list of commands run left to
right: ``/towp/wait/bimg`` waits for the frame the hardware writes next and sends it,
``/bimg`` sends the newest complete frame, ``/frame`` the current frame number as text,
``/trig`` fires one internal trigger (TRIG=4). Facts: reference elphel-stock-camera.md 1.2.
"""

from __future__ import annotations

from elphel_host.errors import CameraClientError

NEXT = "/towp/wait/bimg"
NEWEST = "/bimg"
FRAME = "/frame"
TRIGGER = "/trig"

# What imgsrv sends a frame as: JP4, JP46, a (mono) JPEG, or raw 16-bit TIFF (COLOR 15).
IMAGE_TYPES = ("image/jp4", "image/jp46", "image/jpeg", "image/tiff")


def back_path(frames_back: int) -> str:
    """The path sending the frame ``frames_back`` frames before the newest, from the buffer.

    It also saves that place as the global read pointer (``save``), a fixed place in the
    buffer that `read_pointer_path` steps from: the newest moves on with every frame, the
    read pointer does not.
    """
    return "/last" + "/prev" * frames_back + "/save/bimg"


def read_pointer_path(frames: int) -> str:
    """The path sending the frame ``frames`` after (negative: before) the read pointer."""
    step = "/next" if frames > 0 else "/prev"
    return "/torp" + step * abs(frames) + "/save/bimg"


def frame_number(text: str, *, url: str) -> int:
    """The frame number of a ``/frame`` or ``/wframe`` answer (plain decimal text)."""
    body = text.strip()
    if not body.isdigit():
        raise CameraClientError(f"{url}: imgsrv answered {body[:60]!r}, not a frame number")
    return int(body)


def image_type(content_type: str | None, *, url: str) -> str:
    """The media type of an image answer, checked to be one imgsrv sends frames as."""
    kind = (content_type or "").split(";")[0].strip().lower()
    if kind == "image/gif":
        raise CameraClientError(
            f"{url}: no such frame (imgsrv sent its 1x1 GIF: not taken yet or overwritten)"
        )
    if kind not in IMAGE_TYPES:
        raise CameraClientError(
            f"{url}: imgsrv answered {kind or 'no Content-Type'!r}, not a frame; "
            f"allowed: {', '.join(IMAGE_TYPES)}"
        )
    return kind
