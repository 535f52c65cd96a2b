"""JSON as the standard defines it, read and written with bounds.

Python's `json` accepts and writes ``NaN`` and ``Infinity``, so a camera's
``frame: Infinity`` would end up in a manifest that other tools refuse. `loads` refuses
non-standard numbers, nesting deeper than the parser's recursion limit and texts over a
size limit. Two ways to write, one for each kind of document:

- `dumps`, for files the host reads back (manifests, quad.json, plans, stage models):
  a non-finite value is refused at the door;
- `report_dumps`, for reports (``compare.json``, ``depth.json``, what ``--json``
  prints): a value that is rightly non-finite (the PSNR of an image identical to its
  reference is infinite) is written as ``null`` and named, with its value, under
  ``"non_finite"`` (`NON_FINITE_FIELD`).
"""

from __future__ import annotations

import json
import math
import numbers
from pathlib import Path
from typing import Any

from elphel_host.errors import DeviceAnswerError, DeviceLimitError, InputFormatError
from elphel_host.limits import HostLimits
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


# The field of a report that names the values written as null because JSON has no number
# for them: {"methods.robust.psnr_db": "Infinity", ...}.
NON_FINITE_FIELD = "non_finite"


def _non_finite_name(value: float) -> str:
    if math.isnan(value):
        return "NaN"
    return "Infinity" if value > 0 else "-Infinity"


def _nulled(value: Any, path: str, found: dict[str, str]) -> Any:
    if isinstance(value, numbers.Real) and not math.isfinite(value):
        found[path] = _non_finite_name(float(value))
        return None
    if isinstance(value, dict):
        return {k: _nulled(v, f"{path}.{k}" if path else str(k), found) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_nulled(v, f"{path}.{i}" if path else str(i), found) for i, v in enumerate(value)]
    return value


def nulled(report: dict[str, Any]) -> dict[str, Any]:
    """``report`` with each NaN or infinity as None, named under `NON_FINITE_FIELD`.

    The names are paths of keys and list indices joined by dots (``methods.robust.psnr_db``,
    ``points.3``); their values say which number stood there (``"Infinity"``,
    ``"-Infinity"``, ``"NaN"``). A report with finite numbers only comes back equal, without
    that field.

    Raises
    ------
    ValueError
        The report already has a `NON_FINITE_FIELD` of its own.
    """
    if NON_FINITE_FIELD in report:
        raise ValueError(f"a report may not hold its own {NON_FINITE_FIELD!r} field")
    found: dict[str, str] = {}
    clean = _nulled(report, "", found)
    return {**clean, NON_FINITE_FIELD: found} if found else clean


def report_dumps(report: dict[str, Any], **options: Any) -> str:
    """Strict JSON of a report: non-finite values as null, named (`nulled`)."""
    return json.dumps(nulled(report), allow_nan=False, **options)


def load_file(path: Path) -> Any:
    """The strict JSON document in ``path``; `InputFormatError` when it is not JSON.

    A file over the ``json_bytes`` limit (`HostLimits`) is refused before it is read.
    """
    limits = HostLimits.from_env()
    size = path.stat().st_size
    if size > limits.json_bytes:
        raise InputFormatError(
            f"{path}: {size} bytes; limit json_bytes = {limits.json_bytes} "
            "(raise ELPHEL_LIMIT_JSON_BYTES)"
        )
    try:
        return loads(path.read_bytes(), what=str(path), limit_bytes=limits.json_bytes)
    except ValueError as e:
        raise InputFormatError(str(e)) from e
