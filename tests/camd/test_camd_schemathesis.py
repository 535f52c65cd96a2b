"""Schemathesis against the daemon's own OpenAPI schema: the schema is the contract.

Every operation gets generated requests, valid ones and invalid ones, on the default
board and on the mixed one (MT9P006 + MT9F002 + Lepton 3.5), with the token and without
it, and every check schemathesis has runs on each answer: no server error; status, content
type, headers and body as the schema declares; what the schema allows is accepted (or
refused with a declared 404/409), what it refuses is refused; the declared security is
what the daemon checks (in process schemathesis' own auth probe does not run:
tests/camd/test_security.py compares each operation's declared security with its
answers); ``Allow`` names the path's methods. The example count is bounded
(the full ``schemathesis run URL/openapi.json --checks all`` against ``elphel-sim up`` is
the same contract, run from outside). The event stream is left out: it never ends by
itself (tests/camd/test_security.py and tests/integration/test_camd_cli.py follow it).
"""

from __future__ import annotations

import pytest
import schemathesis
from fastapi import FastAPI
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from schemathesis import GenerationMode
from schemathesis.checks import CHECKS

from elphel_camd.api import create_app
from elphel_camd.api.deps import FailedAuth
from elphel_camd.service import CameraService
from elphel_sim.board import SimCameraBoard
from elphel_sim.scenarios import Scenario, build
from elphel_sim.world import Rig, World

TOKEN = "fuzz-token"
SMALL = {"WOI_WIDTH": 64, "WOI_HEIGHT": 48, "WOI_LEFT": 16, "WOI_TOP": 16}
EXAMPLES = 12


_SCENARIOS: dict[str, Scenario] = {}


def fresh_board(name: str) -> SimCameraBoard:
    """A new board and rig on the scenario's scene, which every board of the module shares.

    The scene is still; its textures (and their filtered copies) are built once.
    """
    if name not in _SCENARIOS:
        _SCENARIOS[name] = build(name, seed=2)
    first = _SCENARIOS[name]
    rig = first.world.rig
    world = World(first.world.scene, Rig(axis=rig.axis, mounts=dict(rig.mounts)))
    return SimCameraBoard(Scenario(world, list(first.ports)), seed=2, noise=False)


def fresh_app(scenario: str):
    # A fresh camera per operation: small windows keep the simulated renders quick.
    camera = CameraService(fresh_board(scenario))
    for port, driver in camera.sensors.items():
        if driver is not None and "WOI_WIDTH" in driver.writable and driver.model != "LEPTON35":
            camera.set_params(port, SMALL)
    camera.board.sim_advance(frames=4)
    app = create_app(camera, token=TOKEN)
    # Wrong tokens are slowed down by design (tests/camd/test_security.py checks the
    # delays); here they only need to be refused.
    app.state.options.failed = FailedAuth(base_s=0.0, max_s=0.0)
    return app, camera


ALL_CHECKS = list(CHECKS.get_all())


@pytest.fixture(scope="module", autouse=True)
def _schemathesis_event_loop():
    """Start the event-loop thread schemathesis keeps for the process, before the tests.

    Its in-process ASGI client runs every app on that one thread, started at the first
    call and kept to the end: started here, it is not a thread a test left running.
    """
    app = FastAPI()
    app.get("/ping")(_ping)
    schemathesis.openapi.from_asgi("/openapi.json", app)


def _ping() -> int:
    return 1


@pytest.mark.parametrize("with_token", [True, False], ids=["token", "no-token"])
@pytest.mark.parametrize("scenario", ["default", "mixed"])
def test_api_conforms_to_its_schema(scenario, with_token):
    headers = {"Authorization": f"Bearer {TOKEN}"} if with_token else {}
    probe, camera = fresh_app(scenario)
    labels = []
    try:
        schema = schemathesis.openapi.from_asgi("/openapi.json", probe)
        operations = [r.ok() for r in schema.get_all_operations()]
    finally:
        camera.close()
    sensor_ports = [p for p, d in camera.sensors.items() if d is not None]
    for op in operations:
        if "/events" in op.label:
            continue
        labels.append(op.label)
        app, camera = fresh_app(scenario)
        operation = schemathesis.openapi.from_asgi("/openapi.json", app)[op.path][op.method.upper()]
        strategy = operation.as_strategy(generation_mode=GenerationMode.POSITIVE) | (
            operation.as_strategy(generation_mode=GenerationMode.NEGATIVE)
        )

        @given(case=strategy, port=st.sampled_from([None, *sensor_ports]))
        @settings(
            max_examples=EXAMPLES,
            deadline=None,
            derandomize=True,
            phases=[Phase.explicit, Phase.generate],
            suppress_health_check=list(HealthCheck),
            database=None,
        )
        def run(case, port):
            params = case.path_parameters
            if port is not None and isinstance(params, dict) and "port" in params:
                params["port"] = port  # a port with a sensor, often
            if case.path.endswith("/preview.mjpeg"):  # a live stream ends only by count
                case.query = {**(case.query or {}), "count": 1}
            if isinstance(case.query, dict) and isinstance(case.query.get("count"), int):
                case.query["count"] = min(case.query["count"], 2)  # bursts render every frame
            # A capture renders a simulated frame: minutes on a loaded machine are not an
            # answer of the daemon's, so the client waits (the daemon's own limits answer).
            case.call_and_validate(headers=headers, checks=ALL_CHECKS, timeout=120)

        try:
            with TestClient(app):
                run()
        finally:
            camera.close()
    assert len(labels) >= 9, labels
