"""The daemon's server-sent events (``GET /api/v1/events``): one event type, one parser."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class CameraEvent:
    """One server-sent event: ``frame``, ``params``, ``error`` or ``dropped``."""

    type: str
    data: dict[str, Any]
    id: int | None = None


@dataclass
class SSEParser:
    """Incremental parser of an event stream's lines."""

    event: str = "message"
    data: list[str] = field(default_factory=list)
    id: int | None = None

    def feed(self, line: str) -> CameraEvent | None:
        if line == "":
            if not self.data:
                self.event = "message"
                return None
            out = CameraEvent(self.event, json.loads("\n".join(self.data)), self.id)
            self.event, self.data, self.id = "message", [], None
            return out
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
