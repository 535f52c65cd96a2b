"""parsedit.php's wire format: the query string it takes and the XML it answers.

``GET /parsedit.php?immediate&sensor_port=N&NAME&NAME=value*K!MASK:value*K...`` reads and
writes frame parameters. This module turns a query string into a `ParseditQuery` (pure,
no camera) and renders the two answers the script gives: the values before the change,
and the error for a name it does not know. What the writes do is
`elphel_sim.stock.firmware.StockFirmware.parsedit`.

Value syntax, as the stock script reads it: an optional ``@`` (read only), then one or
more ``value[*ahead][!mask]`` items separated by ``:``. Numbers are read the way PHP's
``intval`` reads them (leading decimal digits, ``0x`` for hex, anything else 0); an
empty value only reads; a missing ``*ahead`` is 3; a negative one is 0; the mask is hex.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from urllib.parse import parse_qsl

DEFAULT_AHEAD = 3  # frames ahead of a write without "*K"
MAX_AHEAD = 6  # the script writes at most this far ahead of the current frame ...
MIN_AHEAD = 4  # ... and for a farther target waits until it is this far ahead

# Keys the script takes as options, not parameter names.
OPTIONS = frozenset(
    {"immediate", "sensor_port", "title", "shownumbers", "refresh", "test", "showseq"}
    | {"images", "link_images", "embed", "_time"}
)

_INT = re.compile(r"[+-]?\d+")
_HEX = re.compile(r"[0-9a-fA-F]*")


class UnknownParameterError(LookupError):
    """A name the camera has no parameter for (the script's "misspelled constant")."""

    def __init__(self, name: str) -> None:
        super().__init__(f"parsedit.php: no parameter named {name!r}")
        self.name = name


def php_intval(text: str) -> int:
    """A number as parsedit reads one: quotes and spaces trimmed, ``0x`` hex, else intval.

    Like PHP, leading decimal digits count and the rest is ignored; no digits gives 0.
    """
    s = text.strip('" ')
    if s[:2].lower() == "0x":
        digits = _HEX.match(s, 2)
        return int(digits.group(0), 16) if digits and digits.group(0) else 0
    m = _INT.match(s)
    return int(m.group(0)) if m else 0


@dataclass(frozen=True)
class Write:
    """One ``value*ahead!mask`` item: write ``value`` to ``name`` ``ahead`` frames ahead.

    ``mask`` is the hex port mask of ``!MASK`` (None: the request's sensor_port).
    """

    name: str
    value: int
    ahead: int
    mask: int | None = None


@dataclass(frozen=True)
class ParseditQuery:
    """A parsed parsedit.php request.

    ``names`` are the parameters named, in request order (the answer lists them);
    ``writes`` the items that change a value.
    """

    immediate: bool
    sensor_port: int
    names: tuple[str, ...]
    writes: tuple[Write, ...]


def _items(name: str, value: str) -> list[Write]:
    if value.startswith("@"):
        return []  # a read-only monitor
    writes = []
    for item in value.split(":"):
        mask: int | None = None
        if "!" in item:
            item, mask_text = item.split("!", 1)
            digits = _HEX.match(mask_text.strip().removeprefix("0x").removeprefix("0X"))
            mask = int(digits.group(0), 16) if digits and digits.group(0) else 0
        parts = item.split("*")
        ahead = max(php_intval(parts[1]), 0) if len(parts) > 1 else DEFAULT_AHEAD
        if parts[0] == "":
            continue  # no value: only read
        writes.append(Write(name, php_intval(parts[0]), ahead, mask))
    return writes


def parse_query(query: str, *, known: frozenset[str] | set[str]) -> ParseditQuery:
    """Parse a parsedit.php query string.

    Parameters
    ----------
    query
        The raw query string (after ``?``), percent-encoded as sent.
    known
        The parameter names the camera has.

    Raises
    ------
    UnknownParameterError
        For the first key that is neither an option nor a known name (nothing is written).
    """
    fields: dict[str, str] = {}
    for key, value in parse_qsl(query, keep_blank_values=True):
        fields[key] = value  # PHP's $_GET: the last value of a repeated key wins
    names: list[str] = []
    writes: list[Write] = []
    for key, value in fields.items():
        if key in OPTIONS:
            continue
        if key not in known:
            raise UnknownParameterError(key)
        names.append(key)
        writes.extend(_items(key, value))
    return ParseditQuery(
        immediate="immediate" in fields,
        sensor_port=php_intval(fields.get("sensor_port", "0")) & 3,
        names=tuple(names),
        writes=tuple(writes),
    )


def parameters_xml(values: dict[str, int]) -> bytes:
    """The answer to an immediate request: each named parameter's value, decimal."""
    lines = ['<?xml version="1.0"?>', "<parameters>"]
    lines += [f"  <{name}>{value:d}</{name}>" for name, value in values.items()]
    lines.append("</parameters>")
    return ("\n".join(lines) + "\n").encode("ascii")


def unknown_name_xml(name: str) -> bytes:
    """The script's answer to a name it does not know (HTTP 200, nothing written)."""
    text = f"\"Wrong address==0, probably misspelled constant: '{name}'\""
    text = text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    return f'<?xml version="1.0"?>\n<framepars><ERROR>{text}</ERROR></framepars>\n'.encode()
