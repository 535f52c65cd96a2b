"""How much the host takes from a device before it stops listening: sizes and deadlines.

A camera, a stage or a file may claim anything. Every answer is read against a bound
derived from what it claims to be (a frame is at most the largest sensor times its
sample width, a JSON answer has a fixed cap) and every request has an overall deadline,
not only a timeout per read. The bounds are `HostLimits`; each one can be raised with an
environment variable (docs/security.md).
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass

from elphel_host.errors import DeviceLimitError, DeviceTimeout

MIB = 1 << 20


@dataclass(frozen=True)
class HostLimits:
    """The bounds the host holds devices and files to.

    Attributes
    ----------
    json_bytes
        Largest JSON (or XML) answer of a device, and largest JSON file read.
    frame_pixels
        Largest frame, in pixels (a frame's bytes are at most this times 2, its sample
        width). The largest supported sensor, MT9F002, has 4384 x 3288 = 14.4 Mpx.
    burst_frames
        Most frames one multi-frame capture may bring.
    deadline_s
        Overall time one request may take, from sending it to its last byte.
    frame_deadline_s
        Time added to ``deadline_s`` for every frame of a multi-frame capture.
    keepalive_s
        The daemon's event-stream keepalive period; a stream silent for 3 periods is dead.
    event_line_bytes
        Longest line of an event stream.
    event_bytes
        Largest event (its data lines together).
    manifest_frames
        Most frames a burst manifest may list.
    stage_line_bytes
        Longest line a stage board may send.
    jpeg_head_bytes
        Most bytes of a JPEG frame's segments before its Exif block (imgsrv writes it first).
    """

    json_bytes: int = 8 * MIB
    frame_pixels: int = 1 << 24
    burst_frames: int = 4096
    deadline_s: float = 120.0
    frame_deadline_s: float = 5.0
    keepalive_s: float = 15.0
    event_line_bytes: int = 64 * 1024
    event_bytes: int = 1 * MIB
    manifest_frames: int = 10_000
    jpeg_head_bytes: int = 256 * 1024
    stage_line_bytes: int = 4096

    @property
    def frame_bytes(self) -> int:
        """Largest frame in bytes: ``frame_pixels`` 16-bit samples."""
        return self.frame_pixels * 2

    @property
    def event_read_timeout_s(self) -> float:
        """How long an event stream may stay silent: three keepalive periods."""
        return 3.0 * self.keepalive_s

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> HostLimits:
        """The defaults, each replaced by ``ELPHEL_LIMIT_<NAME>`` when that is set.

        Raises `ValueError` naming the variable when a value is not a positive number.
        """
        env = os.environ if environ is None else environ
        values: dict[str, float | int] = {}
        for item in dataclasses.fields(cls):
            name = f"ELPHEL_LIMIT_{item.name.upper()}"
            if name not in env:
                continue
            kind = float if item.type == "float" else int
            try:
                value = kind(env[name])
            except ValueError:
                value = 0
            if not value > 0:
                raise ValueError(f"{name}={env[name]!r}; allowed: a positive {kind.__name__}")
            values[item.name] = value
        return cls(**values)  # type: ignore[arg-type]


class Deadline:
    """An overall deadline on `time.monotonic`, for a request that reads many times."""

    def __init__(self, seconds: float, *, what: str) -> None:
        self.seconds = seconds
        self.what = what
        self.end = time.monotonic() + seconds

    def remaining_s(self) -> float:
        """Seconds left (0 once passed)."""
        return max(0.0, self.end - time.monotonic())

    def check(self) -> None:
        """Raise `DeviceTimeout` once the deadline has passed."""
        if time.monotonic() > self.end:
            raise DeviceTimeout(f"{self.what}: no complete answer within {self.seconds:g} s")


def read_bounded(
    chunks: Iterable[bytes],
    *,
    limit_bytes: int,
    deadline: Deadline,
    what: str,
    limit_name: str,
    into: bytearray | None = None,
) -> bytes:
    """Join ``chunks`` while they stay within ``limit_bytes`` and ``deadline``.

    ``into`` collects the bytes as they arrive (what came before a broken connection).
    Raises `DeviceLimitError` naming ``what`` and the limit when more arrives, and
    `DeviceTimeout` when the deadline passes first.
    """
    data = bytearray() if into is None else into
    for chunk in chunks:
        data += chunk
        if len(data) > limit_bytes:
            raise DeviceLimitError(
                f"{what}: the answer exceeds {limit_bytes} bytes "
                f"(limit {limit_name}; raise ELPHEL_LIMIT_{limit_name.upper()})"
            )
        deadline.check()
    return bytes(data)


def check_declared(length: str | None, *, limit_bytes: int, what: str, limit_name: str) -> None:
    """Refuse an answer whose Content-Length already exceeds ``limit_bytes``."""
    if length is not None and length.strip().isdigit() and int(length) > limit_bytes:
        raise DeviceLimitError(
            f"{what}: claims {int(length)} bytes; limit {limit_name} = {limit_bytes} "
            f"(raise ELPHEL_LIMIT_{limit_name.upper()})"
        )


def bounded_lines(chunks: Iterable[bytes], *, limit_bytes: int, what: str) -> Iterator[str]:
    """Lines of a byte stream (LF or CR LF ends one), each at most ``limit_bytes``.

    Raises `DeviceLimitError` when a line grows past the limit without ending.
    """
    pending = bytearray()
    for chunk in chunks:
        pending += chunk
        *lines, rest = pending.split(b"\n")
        for line in lines:
            if len(line) > limit_bytes:
                raise _line_too_long(what, limit_bytes)
            yield line.removesuffix(b"\r").decode("utf-8", errors="replace")
        if len(rest) > limit_bytes:
            raise _line_too_long(what, limit_bytes)
        pending = bytearray(rest)
    if pending:
        yield pending.removesuffix(b"\r").decode("utf-8", errors="replace")


def _line_too_long(what: str, limit_bytes: int) -> DeviceLimitError:
    return DeviceLimitError(
        f"{what}: a line longer than {limit_bytes} bytes "
        "(limit event_line_bytes; raise ELPHEL_LIMIT_EVENT_LINE_BYTES)"
    )


def check_frame_shape(shape: tuple[int, ...], limits: HostLimits, *, what: str) -> None:
    """Refuse an image whose claimed size exceeds ``limits.frame_pixels``, before decoding it."""
    pixels = 1
    for side in shape:
        pixels *= int(side)
    if pixels > limits.frame_pixels:
        size = "x".join(str(int(s)) for s in shape)
        raise DeviceLimitError(
            f"{what}: claims a {size} image ({pixels} pixels); limit frame_pixels = "
            f"{limits.frame_pixels} (raise ELPHEL_LIMIT_FRAME_PIXELS)"
        )
