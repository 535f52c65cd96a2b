"""Where a stock NC393's services listen, from an ``nc393://`` URL: `NC393Address`.

``nc393://HOST[:HTTP_PORT][?imgsrv=BASE]``: parsedit.php on HTTP_PORT (default 80),
imgsrv on BASE..BASE+3 for sensor ports 0..3 (default 2323, as Elphel's firmware starts
it).
"""

from __future__ import annotations

from dataclasses import dataclass
from urllib.parse import parse_qs, urlsplit

URL_FORMS = (
    "http://HOST:PORT or https://HOST:PORT (elphel-camd), nc393://HOST[:HTTP_PORT][?imgsrv=BASE]"
)
NC393_HTTP_PORT = 80
NC393_IMGSRV_BASE = 2323


@dataclass(frozen=True)
class NC393Address:
    """Where a stock NC393's services listen: parsedit.php and the four imgsrv ports."""

    host: str
    http_port: int = NC393_HTTP_PORT
    imgsrv_base: int = NC393_IMGSRV_BASE

    def imgsrv_url(self, port: int) -> str:
        """Base URL of the imgsrv serving sensor port ``port`` (0..3)."""
        return f"http://{self._netloc(self.imgsrv_base + port)}"

    @property
    def parsedit_url(self) -> str:
        """Base URL of the web server (parsedit.php)."""
        return f"http://{self._netloc(self.http_port)}"

    def _netloc(self, port: int) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{port}"

    @property
    def url(self) -> str:
        """The ``nc393://`` URL naming this address (defaults spelled out)."""
        return f"nc393://{self.host}:{self.http_port}?imgsrv={self.imgsrv_base}"


PORTS = 4  # sensor ports of an NC393, each with its imgsrv


def check_port(port: int) -> None:
    """Raise ValueError unless ``port`` is a sensor port 0..3."""
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port < PORTS:
        raise ValueError(f"sensor port {port!r}; allowed: 0..{PORTS - 1}")


def bad_url(url: str, why: str) -> ValueError:
    return ValueError(f"camera url {url!r}: {why}; allowed: {URL_FORMS}")


def parse_nc393_url(url: str) -> NC393Address:
    """The address in an ``nc393://HOST[:HTTP_PORT][?imgsrv=BASE]`` URL.

    Raises
    ------
    ValueError
        Not that form: another scheme, no host, a path, a port outside 1..65535, an
        imgsrv base whose four ports do not fit below 65536, or another query field.
    """
    parts = urlsplit(url)
    if parts.scheme != "nc393":
        raise bad_url(url, f"scheme {parts.scheme or 'none'!r} is not nc393")
    if not parts.hostname:
        raise bad_url(url, "no host")
    if parts.path not in ("", "/") or parts.fragment or parts.username or parts.password:
        raise bad_url(url, "only a host, a port and ?imgsrv=BASE are allowed")
    try:
        http_port = parts.port if parts.port is not None else NC393_HTTP_PORT
    except ValueError:
        raise bad_url(url, "the port is not a number in 1..65535") from None
    if not 1 <= http_port <= 65535:
        raise bad_url(url, f"port {http_port} is outside 1..65535")
    query = parse_qs(parts.query, keep_blank_values=True, strict_parsing=False)
    extra = sorted(set(query) - {"imgsrv"})
    if extra:
        raise bad_url(url, f"unknown query field(s) {', '.join(extra)}")
    base = NC393_IMGSRV_BASE
    if "imgsrv" in query:
        values = query["imgsrv"]
        if len(values) != 1 or not values[0].isdigit():
            raise bad_url(url, f"imgsrv={','.join(values)!r} is not one port number")
        base = int(values[0])
        if not 1 <= base <= 65535 - 3:
            raise bad_url(url, f"imgsrv={base}: its ports {base}..{base + 3} must lie in 1..65535")
    return NC393Address(host=parts.hostname, http_port=http_port, imgsrv_base=base)
