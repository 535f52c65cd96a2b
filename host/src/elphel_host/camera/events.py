"""The daemon's server-sent events (``GET /api/v1/events``): one event type, one parser."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

from elphel_host.errors import EventStreamError


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
    event and the field; the parser is then ready for the next event.
    """

    event: str = "message"
    data: list[str] = field(default_factory=list)
    id: int | None = None

    def feed(self, line: str) -> CameraEvent | None:
        if line == "":
            if not self.data:
                self.event = "message"
                return None
            event, text, id_ = self.event, "\n".join(self.data), self.id
            self.event, self.data, self.id = "message", [], None
            try:
                data = json.loads(text)
            except (json.JSONDecodeError, RecursionError) as e:
                raise EventStreamError(
                    f"event {event!r} (id {id_}): data={text[:80]!r} is not JSON ({e})"
                ) from e
            if not isinstance(data, dict):
                raise EventStreamError(
                    f"event {event!r} (id {id_}): data={text[:80]!r}; allowed: a JSON object"
                )
            return CameraEvent(event, data, id_)
        if line.startswith(":"):
            return None
        name, _, value = line.partition(":")
        value = value.removeprefix(" ")
        if name == "event":
            self.event = value
        elif name == "data":
            self.data.append(value)
        elif name == "id" and value.isdigit():
            self.id = int(value)
        return None
