"""A camera URL picks the backend: `connect` and the URL forms it accepts.

``http(s)://HOST:PORT`` is elphel-camd (`CameraClient`); ``nc393://HOST[:HTTP_PORT]
[?imgsrv=BASE]`` is a stock NC393 running Elphel's own firmware (`NC393Client`):
parsedit.php on HTTP_PORT (default 80), imgsrv on BASE..BASE+3 for sensor ports 0..3
(default 2323).
"""

from __future__ import annotations

import re
from typing import Any
from urllib.parse import urlsplit

from elphel_host.camera.client import CameraClient
from elphel_host.camera.nc393.address import bad_url, parse_nc393_url
from elphel_host.camera.protocol import CameraInterface


def connect(url: str, token: str | None = None, **options: Any) -> CameraInterface:
    """The camera at ``url``, through the backend its scheme names.

    Parameters
    ----------
    url
        ``http(s)://HOST:PORT`` (elphel-camd) or ``nc393://HOST[:HTTP_PORT][?imgsrv=BASE]``
        (a stock NC393).
    token
        elphel-camd's bearer token. A stock NC393 has no authentication of any kind: the
        token is not used there (so one ``ELPHEL_CAMERA_TOKEN`` can serve both kinds).
    **options
        Passed to the backend (``timeout_s``, and for tests ``transport``).

    Returns
    -------
    CameraInterface
        A `CameraClient` or an `NC393Client`.

    Raises
    ------
    ValueError
        A URL of neither form (the message names it and the allowed forms).

    Notes
    -----
    ``HOST:PORT`` without a scheme is taken as ``http://HOST:PORT``, and the API's own
    path (``http://HOST:PORT/api/v1``) as the daemon's base URL.
    """
    base = camd_base_url(url)
    scheme = urlsplit(base).scheme
    if scheme in ("http", "https"):
        if not urlsplit(base).hostname:
            raise bad_url(url, "no host")
        return CameraClient(base, token, **options)
    if scheme == "nc393":
        # imported here: elphel-camd users do not load the stock camera's parameter model
        from elphel_host.camera.nc393.client import NC393Client

        return NC393Client(parse_nc393_url(url), **options)
    raise bad_url(url, f"scheme {scheme or 'none'!r} names no camera backend")


def camd_base_url(url: str) -> str:
    """``url`` as elphel-camd's base URL when it is one in another spelling.

    ``HOST:PORT`` (no scheme) becomes ``http://HOST:PORT``; a trailing ``/api/v1`` (the
    API's path, which the client adds itself) is dropped. Other URLs are returned as given.
    """
    text = url.strip()
    if "://" not in text and re.fullmatch(r"[\w.-]+:\d+/?(api/v1/?)?", text):
        text = f"http://{text}"
    if text.startswith(("http://", "https://")):
        text = re.sub(r"/api/v1/?$", "", text.rstrip("/"))
    return text
