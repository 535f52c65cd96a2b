"""REST client for elphel-camd (shared/DESIGN.md section 4.2)."""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from types import TracebackType
from typing import Any

import httpx
import numpy as np
import tifffile
from numpy.typing import NDArray

from elphel_host.errors import CameraAuthError, CameraClientError

API = "/api/v1"


@dataclass(frozen=True)
class CapturedFrame:
    """A frame as the daemon sent it: the TIFF bytes, the image and its metadata."""

    tiff: bytes
    image: NDArray[np.uint16]
    metadata: dict[str, Any]

    @property
    def frame(self) -> int:
        return int(self.metadata["frame"])


def read_tiff_metadata(data: bytes | str) -> tuple[NDArray[Any], dict[str, Any]]:
    """Image and JSON metadata (ImageDescription) of a TIFF written by the daemon."""
    source: Any = io.BytesIO(data) if isinstance(data, bytes) else data
    with tifffile.TiffFile(source) as tif:
        image = tif.asarray()
        description = tif.pages.first.description
    try:
        metadata = json.loads(description) if description else {}
    except json.JSONDecodeError as e:
        raise CameraClientError(f"TIFF ImageDescription is not JSON metadata: {e}") from e
    metadata.pop("shape", None)
    return image, metadata


class CameraClient:
    """Talks to one camera daemon.

    Parameters
    ----------
    url
        Base URL of the daemon, e.g. ``http://127.0.0.1:8000``.
    token
        Bearer token for writes (capture counts as one); None for read-only use.
    timeout_s
        Per-request timeout.
    """

    def __init__(self, url: str, token: str | None = None, *, timeout_s: float = 30.0) -> None:
        if not url.startswith(("http://", "https://")):
            raise ValueError(f"camera url {url!r}; allowed: http://HOST:PORT or https://...")
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.url = url.rstrip("/")
        self._http = httpx.Client(base_url=self.url + API, headers=headers, timeout=timeout_s)

    def __enter__(self) -> CameraClient:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    def _request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        try:
            response = self._http.request(method, path, **kwargs)
        except httpx.HTTPError as e:
            raise CameraClientError(f"cannot reach the camera at {self.url}: {e}") from e
        if response.status_code >= 400:
            try:
                detail = response.json().get("detail", response.text)
            except (json.JSONDecodeError, AttributeError):
                detail = response.text
            message = f"{method} {path}: HTTP {response.status_code}: {detail}"
            if response.status_code in (401, 403):
                raise CameraAuthError(message)
            raise CameraClientError(message)
        return response

    def info(self) -> dict[str, Any]:
        """Board, daemon version and ports with their sensors."""
        result: dict[str, Any] = self._request("GET", "/info").json()
        return result

    def capture(self, port: int = 0) -> CapturedFrame:
        """The next frame of a port."""
        response = self._request("POST", f"/ports/{port}/capture")
        image, metadata = read_tiff_metadata(response.content)
        return CapturedFrame(tiff=response.content, image=image, metadata=metadata)
