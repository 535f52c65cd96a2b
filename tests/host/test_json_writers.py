"""Every JSON the host writes is strict JSON: no NaN, no Infinity.

Files the host reads back refuse a non-finite value before anything is written; reports
(compare.json, depth.json, what --json prints) write it as null and name it under
"non_finite". A source check keeps every other writer on one of those two paths.
"""

from __future__ import annotations

import ast
import json
import math
from pathlib import Path

import numpy as np
import pytest

from elphel_host import strict_json
from elphel_host.burst.plan import BurstPlan, write_plan
from elphel_host.cli_common import emit

HOST_SRC = Path(__file__).resolve().parents[2] / "host" / "src" / "elphel_host"


def _refuse(name: str) -> None:
    raise AssertionError(f"{name} is not strict JSON")


def strict_loads(text: str):
    return json.loads(text, parse_constant=_refuse)


def _json_dump_calls(tree: ast.AST):
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr in ("dump", "dumps")
            and isinstance(node.func.value, ast.Name)
            and node.func.value.id == "json"
        ):
            yield node


def _refuses_nan(keyword: ast.keyword) -> bool:
    value = keyword.value
    return keyword.arg == "allow_nan" and isinstance(value, ast.Constant) and value.value is False


def test_every_json_writer_of_the_host_refuses_non_finite_numbers():
    """Outside strict_json.py, json.dump(s) is called only with allow_nan=False."""
    loose = []
    for path in sorted(HOST_SRC.rglob("*.py")):
        if path.name == "strict_json.py":
            continue
        for call in _json_dump_calls(ast.parse(path.read_text(), str(path))):
            if not any(_refuses_nan(k) for k in call.keywords):
                loose.append(f"{path.relative_to(HOST_SRC)}:{call.lineno}")
    assert loose == [], "use strict_json.dumps or strict_json.report_dumps"


def test_the_source_check_finds_a_loose_writer():
    tree = ast.parse("import json\njson.dumps(x)\njson.dumps(x, allow_nan=False)\n")
    calls = list(_json_dump_calls(tree))
    assert [c.lineno for c in calls] == [2, 3]
    assert [k.arg for k in calls[0].keywords] == []


def test_a_report_names_each_non_finite_value_and_writes_null():
    report = {
        "methods": {"robust": {"psnr_db": math.inf, "ssim": 1.0}, "bicubic": {"psnr_db": 31.5}},
        "points": [1.0, np.float32("nan"), -np.inf],
        "name": "x",
    }
    doc = strict_loads(strict_json.report_dumps(report, sort_keys=True))
    assert doc["methods"]["robust"] == {"psnr_db": None, "ssim": 1.0}
    assert doc["methods"]["bicubic"] == {"psnr_db": 31.5}
    assert doc["points"] == [1.0, None, None]
    assert doc["non_finite"] == {
        "methods.robust.psnr_db": "Infinity",
        "points.1": "NaN",
        "points.2": "-Infinity",
    }


def test_a_finite_report_is_written_as_it_is():
    report = {"a": [1, 2.5, True, None], "b": {"c": "d"}}
    assert strict_loads(strict_json.report_dumps(report)) == report


def test_a_report_with_its_own_non_finite_field_is_refused():
    with pytest.raises(ValueError, match="non_finite"):
        strict_json.report_dumps({"non_finite": {}})


def test_json_output_of_a_command_is_strict(capsys):
    class Args:
        json = True

    emit(Args(), {"psnr_db": math.inf}, "human")  # type: ignore[arg-type]
    doc = strict_loads(capsys.readouterr().out)
    assert doc == {"psnr_db": None, "non_finite": {"psnr_db": "Infinity"}}


def test_a_plan_with_a_non_finite_number_is_refused_and_not_written(tmp_path):
    path = tmp_path / "plan.json"
    with pytest.raises(ValueError, match="non-finite"):
        write_plan(path, BurstPlan(positions_mm=[0.0, math.nan]))
    assert list(tmp_path.iterdir()) == []
    write_plan(path, BurstPlan(positions_mm=[0.0, 0.5]))
    assert strict_loads(path.read_text())["positions_mm"] == [0.0, 0.5]
