"""One GET to a stock NC393's web server or imgsrv, with its failures as one line each."""

from __future__ import annotations

import httpx

from elphel_host.errors import CameraClientError


def http_get(client: httpx.Client, path: str) -> httpx.Response:
    """GET ``path``; an unreachable camera or an HTTP error is a `CameraClientError`.

    The message names the URL and, for an error status, the answer's first line.
    """
    where = str(client.base_url).rstrip("/") + path
    try:
        response = client.get(path)
    except httpx.HTTPError as e:
        raise CameraClientError(f"cannot reach the camera at {where}: {e}") from e
    if response.status_code >= 400:
        first = response.text.strip().splitlines()[0][:120] if response.text.strip() else ""
        raise CameraClientError(f"{where}: HTTP {response.status_code}: {first!r}")
    return response
