"""Schemathesis against the daemon's own OpenAPI schema on the simulated board.

Every operation gets generated requests; no answer may be a server error or contradict
the schema (status code, content type, body). The event stream is left out: it never
ends by itself (tests/integration/test_camd_cli.py follows it).
"""

import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from schemathesis.checks import (
    content_type_conformance,
    not_a_server_error,
    response_schema_conformance,
    status_code_conformance,
)

from elphel_camd.api import create_app
from elphel_camd.service import CameraService
from elphel_sim.board import SimCameraBoard
from elphel_sim.scenarios import build

TOKEN = "fuzz-token"
SMALL = {"WOI_WIDTH": 64, "WOI_HEIGHT": 48, "WOI_LEFT": 1200, "WOI_TOP": 900}


def fresh_app():
    # A fresh camera per operation: a small window keeps the simulated renders quick.
    camera = CameraService(SimCameraBoard(build("default", seed=2), seed=2, noise=False))
    camera.set_params(0, SMALL)
    camera.board.sim_advance(frames=4)
    return create_app(camera, token=TOKEN)


CHECKS = [
    not_a_server_error,
    status_code_conformance,
    content_type_conformance,
    response_schema_conformance,
]


def test_api_conforms_to_its_schema():
    labels = []
    for result in schemathesis.openapi.from_asgi("/openapi.json", fresh_app()).get_all_operations():
        label = result.ok().label
        if "/events" in label:
            continue
        labels.append(label)
        app = fresh_app()
        operation = schemathesis.openapi.from_asgi("/openapi.json", app)[result.ok().path][
            result.ok().method.upper()
        ]

        @given(case=operation.as_strategy(), on_port_0=st.booleans())
        @settings(
            max_examples=20,
            deadline=None,
            derandomize=True,
            phases=[Phase.explicit, Phase.generate],
            suppress_health_check=list(HealthCheck),
            database=None,
        )
        def run(case, on_port_0):
            if on_port_0 and case.path_parameters and "port" in case.path_parameters:
                case.path_parameters["port"] = 0  # the port with a sensor, most of the time
            if case.path.endswith("/preview.mjpeg"):  # a live stream ends only by count
                case.query = {**(case.query or {}), "count": 1}
            if case.query and isinstance(case.query.get("count"), int):
                case.query["count"] = min(case.query["count"], 3)  # bursts render every frame
            case.call_and_validate(headers={"Authorization": f"Bearer {TOKEN}"}, checks=CHECKS)

        with TestClient(app):
            run()
    assert len(labels) >= 9, labels
