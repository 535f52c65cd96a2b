"""The longest exposure the schema advertises is one the daemon accepts and keeps.

EXPOS is rounded to whole rows. The upper limit was once the longest exposure rounded
down to a whole µs, while the exposure of that many rows is reported rounded to the
nearest µs: writing the limit gave an EXPOS one µs above it, refused the next time the
state was checked (any later change).
"""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from elphel_camd.api import create_app
from elphel_camd.service import CameraService
from elphel_sim.board import SimCameraBoard
from elphel_sim.scenarios import build

TOKEN = "test-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
# Widths whose longest exposure has a fractional µs of .5 or more (the case that failed)
# and of less; the full width of each sensor.
WIDTHS = {0: (320, 64, 1000, 2592), 1: (320, 642, 1290, 4384)}


@pytest.fixture(scope="module")
def client():
    board = SimCameraBoard(build("mixed", seed=2), seed=2)
    camera = CameraService(board)
    with TestClient(create_app(camera, token=TOKEN)) as c:
        yield c, board
    camera.close()


def patch(rig: tuple[TestClient, SimCameraBoard], port: int, body: dict[str, int]) -> dict:
    """PATCH the port's parameters and let the frames pass until they are in effect."""
    client, board = rig
    r = client.patch(f"/api/v1/ports/{port}/params", json=body, headers=AUTH)
    board.sim_advance(frames=4, port=port)
    return {"status": r.status_code, **r.json()}


@pytest.mark.parametrize(
    ("port", "width"), [(p, w) for p, widths in WIDTHS.items() for w in widths]
)
def test_the_advertised_longest_exposure_is_accepted_and_stays(client, port, width):
    assert patch(client, port, {"EXPOS": 1000})["status"] == 200
    window = {"WOI_WIDTH": width, "WOI_HEIGHT": 240, "WOI_LEFT": 0, "WOI_TOP": 0}
    assert patch(client, port, window)["status"] == 200
    schema = client[0].get(f"/api/v1/ports/{port}/params/schema", headers=AUTH).json()
    high = schema["params"]["EXPOS"]["maximum"]
    rows = schema["params"]["VEXPOS"]["maximum"]
    got = patch(client, port, {"EXPOS": high})
    assert got["status"] == 200, got
    assert got["params"]["EXPOS"] == high and got["params"]["VEXPOS"] == rows
    # The state is checked again with the next change: the exposure is still allowed.
    again = patch(client, port, {"GAINR": 0x20000})
    assert again["status"] == 200, again
    assert again["params"]["EXPOS"] == high
    # Writing the rows gives the same EXPOS; one µs more is refused, naming the limit.
    assert patch(client, port, {"VEXPOS": rows})["params"]["EXPOS"] == high
    over = patch(client, port, {"EXPOS": high + 1})
    assert over["status"] == 409 and over["allowed"] == f"1..{high}", over
