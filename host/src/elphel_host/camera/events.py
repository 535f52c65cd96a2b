"""The daemon's server-sent events (``GET /api/v1/events``): one event type, one parser."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

from elphel_host.errors import DeviceLimitError, EventStreamError
from elphel_host.shown import shown


@dataclass(frozen=True)
class CameraEvent:
    """One server-sent event: ``frame``, ``params``, ``error`` or ``dropped``."""

    type: str
    data: dict[str, Any]
    id: int | None = None


@dataclass
class SSEParser:
    """Incremental parser of an event stream's lines.

    An event whose ``data`` is not one JSON object raises `EventStreamError` naming the
    event and the field; the parser is then ready for the next event. An event whose
    data lines together exceed ``limit_bytes`` raises `DeviceLimitError` naming ``what``.
    """

    limit_bytes: int = 1 << 20
    what: str = "the event stream"
    event: str = "message"
    data: list[str] = field(default_factory=list)
    id: int | None = None
    size: int = 0

    def feed(self, line: str) -> CameraEvent | None:
        if line == "":
            if not self.data:
                self.event = "message"
                return None
            event, text, id_ = self.event, "\n".join(self.data), self.id
            self.event, self.data, self.id, self.size = "message", [], None, 0
            name = shown(event, limit_chars=40)
            try:
                data = json.loads(text, parse_constant=_refuse_constant)
            except (ValueError, RecursionError) as e:
                raise EventStreamError(
                    f"event {name!r} (id {id_}): data={shown(text, limit_chars=80)} is not "
                    f"JSON ({shown(e, limit_chars=80)})"
                ) from e
            if not isinstance(data, dict):
                raise EventStreamError(
                    f"event {name!r} (id {id_}): data={shown(text, limit_chars=80)}; "
                    "allowed: a JSON object"
                )
            return CameraEvent(event, data, id_)
        if line.startswith(":"):
            return None
        name, _, value = line.partition(":")
        value = value.removeprefix(" ")
        if name == "event":
            self.event = value
        elif name == "data":
            self.size += len(value) + 1
            if self.size > self.limit_bytes:
                self.event, self.data, self.id, self.size = "message", [], None, 0
                raise DeviceLimitError(
                    f"{self.what}: an event longer than {self.limit_bytes} bytes "
                    "(limit event_bytes; raise ELPHEL_LIMIT_EVENT_BYTES)"
                )
            self.data.append(value)
        elif name == "id" and value.isdigit():
            self.id = int(value)
        return None


def _refuse_constant(name: str) -> object:
    raise ValueError(f"{name} is not a JSON number")
