"""One GET to a stock NC393's web server or imgsrv, bounded, with its failures as one line each."""

from __future__ import annotations

from dataclasses import dataclass

import httpx

from elphel_host.errors import CameraClientError, DeviceTimeout
from elphel_host.limits import Deadline, HostLimits, check_declared, read_bounded


@dataclass(frozen=True)
class Answer:
    """An answer read whole: its headers and body."""

    headers: httpx.Headers
    content: bytes

    @property
    def text(self) -> str:
        return self.content.decode("utf-8", errors="replace")


def readable_path(path: str) -> str:
    """``path`` with each run of one repeated imgsrv command written once with its count.

    ``/last/prev/prev/prev/save/bimg`` reads ``/last/prev*3/save/bimg``: a walk far back in
    imgsrv's buffer would otherwise fill a message with its ``prev`` commands.
    """
    parts = path.split("/")
    out: list[str] = []
    i = 0
    while i < len(parts):
        run = 1
        while i + run < len(parts) and parts[i + run] == parts[i]:
            run += 1
        out.append(parts[i] if run == 1 else f"{parts[i]}*{run}")
        i += run
    return "/".join(out)


def http_get(client: httpx.Client, path: str, *, limits: HostLimits, frame: bool = False) -> Answer:
    """GET ``path`` within ``limits``: an XML/text answer (``frame``: an image) and the deadline.

    An unreachable camera or an HTTP error is a `CameraClientError` naming the URL and,
    for an error status, the answer's first line; an answer over its limit is a
    `DeviceLimitError`, one past the deadline or the client's timeout a `DeviceTimeout`.
    """
    where = str(client.base_url).rstrip("/") + readable_path(path)
    limit, name = (
        (limits.frame_bytes + limits.json_bytes, "frame_pixels")
        if frame
        else (limits.json_bytes, "json_bytes")
    )
    deadline = Deadline(limits.deadline_s, what=f"GET {path}")
    what = f"the camera at {where}"
    try:
        with client.stream("GET", path) as response:
            if response.status_code >= 400:
                body = read_bounded(
                    response.iter_bytes(),
                    limit_bytes=limits.json_bytes,
                    deadline=deadline,
                    what=what,
                    limit_name="json_bytes",
                ).decode("utf-8", errors="replace")
                first = body.strip().splitlines()[0][:120] if body.strip() else ""
                # repr escapes the control characters a terminal would obey.
                raise CameraClientError(f"{where}: HTTP {response.status_code}: {first!r}")
            length = response.headers.get("content-length")
            check_declared(length, limit_bytes=limit, what=what, limit_name=name)
            content = read_bounded(
                response.iter_bytes(),
                limit_bytes=limit,
                deadline=deadline,
                what=what,
                limit_name=name,
            )
            return Answer(response.headers, content)
    except httpx.TimeoutException as e:
        raise DeviceTimeout(f"the camera at {where} did not answer in time: {e}") from e
    except httpx.HTTPError as e:
        raise CameraClientError(f"cannot reach the camera at {where}: {e}") from e
