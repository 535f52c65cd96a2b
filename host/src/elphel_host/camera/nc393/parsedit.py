"""parsedit.php on the wire: the query strings a stock NC393 takes and the XML it answers.

``/parsedit.php?immediate&sensor_port=N&EXPOS&FRAME`` reads; ``NAME=value*K`` writes the
value K frames ahead, ``NAME=value*K!MASK`` to the ports in the hex mask (order value,
ahead, mask is fixed). The answer is ``<parameters><NAME>value</NAME>...</parameters>``
holding the values *before* the change. Facts: reference elphel-stock-camera.md 1.1.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping

from elphel_host.errors import CameraClientError

PATH = "/parsedit.php"


def read_query(port: int, names: Iterable[str]) -> str:
    """Query string reading ``names`` of sensor port ``port`` now."""
    return "&".join(["immediate", f"sensor_port={port}", *names])


def write_query(
    port: int,
    changes: Mapping[str, int],
    *,
    ahead: int,
    mask: int | None = None,
    read: Iterable[str] = ("FRAME",),
) -> str:
    """Query string writing ``changes`` ``ahead`` frames on (to the ports in ``mask``).

    ``read`` names are asked in the same request, so their values (``FRAME`` above all)
    are those of the instant the script schedules the change.
    """
    suffix = f"*{ahead}" + ("" if mask is None else f"!{mask:x}")
    writes = [f"{name}={int(value)}{suffix}" for name, value in changes.items()]
    return "&".join(["immediate", f"sensor_port={port}", *writes, *read])


def parse_answer(text: str, *, url: str, names: Iterable[str]) -> dict[str, int]:
    """The values of an answer, checked to hold every name asked.

    Raises
    ------
    CameraClientError
        The script's error answer (``<ERROR>``, e.g. for a name it does not know), an
        answer that is not parsedit's XML, a value that is not an integer, or a name asked
        that the answer lacks.
    """
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        first = text.strip().splitlines()[0][:120] if text.strip() else "an empty answer"
        raise CameraClientError(f"{url}: not a parsedit.php XML answer ({e}): {first!r}") from e
    error = root.find("ERROR")
    if error is not None:
        text = " ".join((error.text or "").split()).strip('"')
        raise CameraClientError(f"{url}: parsedit.php error: {text}")
    if root.tag != "parameters":
        raise CameraClientError(f"{url}: parsedit.php answered <{root.tag}>, not <parameters>")
    values: dict[str, int] = {}
    for child in root:
        body = (child.text or "").strip()
        try:
            values[child.tag] = int(body)
        except ValueError:
            raise CameraClientError(
                f"{url}: parsedit.php answered {child.tag}={body!r}, not an integer"
            ) from None
    missing = [n for n in names if n not in values]
    if missing:
        raise CameraClientError(
            f"{url}: parsedit.php did not answer {', '.join(missing)} "
            "(a parameter this camera's firmware does not know?)"
        )
    return values
