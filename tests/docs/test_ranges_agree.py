"""One range per parameter: the daemon's refusals, the browser page, the CLI and the docs agree.

For the window of an MT9P006 port, the range a 422 (the schema's check) and a 409 (the
sensor's) name, the limits the page labels its fields with (``params/schema``), the
range ``elphel camera params`` shows and the rows of docs/sensors.md and the examples of
docs/quickstart.md and docs/browser.md are the same sensor range.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from elphel_camd.api import create_app
from elphel_camd.service import CameraService
from elphel_host.camera.param_table import param_rows, table_schema
from elphel_sim.board import SimCameraBoard
from elphel_sim.scenarios import build

DOCS = Path(__file__).resolve().parents[2] / "docs"
AUTH = {"Authorization": "Bearer t"}
# name -> a value the schema refuses (odd), one it refuses as too big, one only the sensor does
CASES = {"WOI_WIDTH": (641, 70000, 2594), "WOI_HEIGHT": (481, 70000, 1946)}


@pytest.fixture(scope="module")
def api():
    service = CameraService(SimCameraBoard(build("default", seed=0), seed=0))
    try:
        with TestClient(create_app(service, token="t")) as client:
            yield client
    finally:
        service.close()


def refusal(api: TestClient, name: str, value: int) -> str:
    r = api.patch("/api/v1/ports/0/params", json={name: value}, headers=AUTH)
    assert r.status_code in (409, 422), r.text
    body = r.json()
    assert body["detail"].endswith(f"allowed: {body['allowed']}"), body
    return str(body["allowed"])


@pytest.mark.parametrize("name", sorted(CASES))
def test_daemon_page_and_cli_name_the_sensor_range(api, name) -> None:
    page = api.get("/api/v1/ports/0/params/schema", headers=AUTH).json()["params"][name]
    expected = f"{page['minimum']}..{page['maximum']} (even)"
    assert page["maximum"] < 65535  # the sensor's, not the schema's widest
    assert {refusal(api, name, v) for v in CASES[name]} == {expected}
    values = api.get("/api/v1/ports/0/params", headers=AUTH).json()
    rows = param_rows(table_schema(), values, sensor_code=values["SENSOR"], port=0)
    assert next(r.range for r in rows if r.name == name) == expected


def test_docs_name_the_same_ranges(api) -> None:
    schema = api.get("/api/v1/ports/0/params/schema", headers=AUTH).json()["params"]
    width = f"{schema['WOI_WIDTH']['minimum']}..{schema['WOI_WIDTH']['maximum']}"
    height = f"{schema['WOI_HEIGHT']['minimum']}..{schema['WOI_HEIGHT']['maximum']}"
    sensors = (DOCS / "sensors.md").read_text()
    assert f"| `WOI_WIDTH` | pixels | {width}, even |" in sensors
    assert f"| `WOI_HEIGHT` | pixels | {height}, even;" in sensors
    quoted = re.findall(
        r"WOI_WIDTH=\d+ [^`]*?allowed: ([\d.]+) \(even\)",
        " ".join(
            (DOCS / page).read_text()
            for page in ("sensors.md", "quickstart.md", "browser.md", "rest-api.md")
        ),
    )
    assert quoted and set(quoted) == {width}, quoted
    rest = json.dumps(refusal(api, "WOI_WIDTH", 3000))
    assert rest == json.dumps(f"{width} (even)")
