"""JSON as the standard defines it, read and written with bounds.

Python's `json` accepts and writes ``NaN`` and ``Infinity``, so a camera's
``frame: Infinity`` would end up in a manifest that other tools refuse. `loads` refuses
non-standard numbers, nesting deeper than the parser's recursion limit and texts over a
size limit; `dumps` refuses non-finite values at the door.
"""

from __future__ import annotations

import json
import math
from typing import Any

from elphel_host.errors import DeviceAnswerError, DeviceLimitError
from elphel_host.shown import shown


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a JSON number")


def _finite(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"{text[:40]} overflows a double; allowed: finite numbers")
    return value


def loads(data: bytes | str, *, what: str, limit_bytes: int) -> Any:
    """Parse strict JSON from ``what`` (a device or file, for messages).

    Raises
    ------
    DeviceLimitError
        More than ``limit_bytes``, or nested deeper than the parser's recursion limit.
    DeviceAnswerError
        Not JSON, or with ``NaN``/``Infinity`` or a number too large for a double.
    """
    if len(data) > limit_bytes:
        raise DeviceLimitError(
            f"{what}: {len(data)} bytes of JSON; limit json_bytes = {limit_bytes} "
            "(raise ELPHEL_LIMIT_JSON_BYTES)"
        )
    try:
        text = data.decode("utf-8") if isinstance(data, bytes) else data
    except UnicodeDecodeError as e:
        raise DeviceAnswerError(f"{what}: not UTF-8 JSON ({e.reason} at byte {e.start})") from e
    try:
        return json.loads(text, parse_constant=_refuse_constant, parse_float=_finite)
    except RecursionError as e:
        raise DeviceLimitError(f"{what}: JSON nested deeper than the parser allows") from e
    except ValueError as e:
        raise DeviceAnswerError(f"{what}: not valid JSON ({shown(e, limit_chars=120)})") from e


def dumps(value: Any, *, what: str, **options: Any) -> str:
    """Strict JSON of ``value``; a NaN or infinity raises `DeviceAnswerError` naming ``what``."""
    try:
        return json.dumps(value, allow_nan=False, **options)
    except ValueError as e:
        raise DeviceAnswerError(
            f"{what}: holds a non-finite number (NaN or infinity); allowed: finite numbers"
        ) from e
