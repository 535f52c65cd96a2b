"""A small HTTP/1.1 client on asyncio streams for the load benchmark (not a benchmark itself).

One keep-alive connection per client, requests one after another on it, answers with
``Content-Length`` or chunked bodies. It does a fraction of httpx's work per request: a
load generator on the same machine as the daemon must not take the CPU the daemon's
latency is measured with.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator, Mapping
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlencode


class TransportError(Exception):
    """The connection failed or the answer was not HTTP/1.1 as expected."""


@dataclass
class Answer:
    status: int
    headers: dict[str, str]
    body: bytes

    def json(self) -> Any:
        return json.loads(self.body)

    @property
    def text(self) -> str:
        return self.body.decode("utf-8", "replace")


class Connection:
    """A keep-alive HTTP/1.1 connection to ``host:port`` (reopened when the server closes it)."""

    def __init__(self, url: str, headers: Mapping[str, str] | None = None) -> None:
        host, port = url.removeprefix("http://").split(":")
        self.host, self.port = host, int(port)
        self.headers = {"Host": f"{host}:{port}", **(headers or {})}
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None

    async def _open(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        if self._reader is None or self._writer is None or self._writer.is_closing():
            self._reader, self._writer = await asyncio.open_connection(self.host, self.port)
        return self._reader, self._writer

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
        self._reader = self._writer = None

    def _head(self, method: str, path: str, params: Mapping[str, Any] | None, body: bytes) -> bytes:
        target = f"{path}?{urlencode(params)}" if params else path
        lines = [f"{method} {target} HTTP/1.1", *(f"{k}: {v}" for k, v in self.headers.items())]
        if body or method in ("POST", "PUT", "PATCH"):
            lines.append(f"Content-Length: {len(body)}")
        if body:
            lines.append("Content-Type: application/json")
        return ("\r\n".join(lines) + "\r\n\r\n").encode()

    async def send(
        self,
        method: str,
        path: str,
        *,
        params: Mapping[str, Any] | None = None,
        json_body: Any = None,
    ) -> tuple[int, dict[str, str], asyncio.StreamReader]:
        """Send a request; return the answer's status, headers and the reader at its body."""
        body = b"" if json_body is None else json.dumps(json_body).encode()
        try:
            reader, writer = await self._open()
            writer.write(self._head(method, path, params, body) + body)
            head = await reader.readuntil(b"\r\n\r\n")
        except (OSError, asyncio.IncompleteReadError, asyncio.LimitOverrunError) as e:
            self.close()
            raise TransportError(f"{method} {path}: {type(e).__name__}: {e}") from e
        status_line, *header_lines = head.decode("latin-1").split("\r\n")
        parts = status_line.split(" ", 2)
        if len(parts) < 2 or not parts[0].startswith("HTTP/1."):
            self.close()
            raise TransportError(f"{method} {path}: not an HTTP answer: {status_line!r}")
        headers = {}
        for line in header_lines:
            if line:
                name, _, value = line.partition(":")
                headers[name.strip().lower()] = value.strip()
        return int(parts[1]), headers, reader

    async def body_chunks(self, headers: Mapping[str, str]) -> AsyncIterator[bytes]:
        """The answer's body, as it arrives."""
        assert self._reader is not None
        reader = self._reader
        try:
            if headers.get("transfer-encoding", "").lower() == "chunked":
                while True:
                    size = int((await reader.readuntil(b"\r\n")).split(b";")[0], 16)
                    if size == 0:
                        await reader.readuntil(b"\r\n")
                        break
                    chunk = await reader.readexactly(size + 2)
                    yield chunk[:-2]
            else:
                remaining = int(headers.get("content-length", "0"))
                while remaining > 0:
                    chunk = await reader.read(min(remaining, 1 << 20))
                    if not chunk:
                        raise asyncio.IncompleteReadError(b"", remaining)
                    remaining -= len(chunk)
                    yield chunk
        except (OSError, ValueError, asyncio.IncompleteReadError, asyncio.LimitOverrunError) as e:
            self.close()
            raise TransportError(f"body: {type(e).__name__}: {e}") from e
        if headers.get("connection", "").lower() == "close":
            self.close()

    async def request(
        self,
        method: str,
        path: str,
        *,
        params: Mapping[str, Any] | None = None,
        json_body: Any = None,
    ) -> Answer:
        """One whole request and answer."""
        status, headers, _ = await self.send(method, path, params=params, json_body=json_body)
        body = b"".join([chunk async for chunk in self.body_chunks(headers)])
        return Answer(status, headers, body)
