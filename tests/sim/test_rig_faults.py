"""The ``elphel_rig`` fixture's fault hooks, seen the way a user's own code sees them.

Each fault is injected into a running ``elphel-sim up`` through ``{sim_url}/faults`` (the
`Rig` helpers), shows up in the camera or stage client as the hardware fault would, and
clearing the faults brings back normal work.
"""

from __future__ import annotations

import threading
from typing import Any

import httpx
import pytest

from elphel_host.camera import CameraClient
from elphel_host.camera.client import CameraHTTPError
from elphel_host.errors import StageConnectionError, StageStallError, StageTimeout
from elphel_host.stage import Positioner, StageClient
from elphel_sim.pytest_plugin import Rig

RED_GAIN = 0x2D  # MT9P006 register; the sensor of port 0 sits at I2C address 0x48


def true_mm(rig: Rig) -> float:
    s = httpx.get(f"{rig.sim_url}/stage", timeout=10).json()
    return float(s["true_mm"] - s["caliper_zero_mm"])


def test_i2c_nak_is_the_daemons_i2c_error_naming_port_and_register(elphel_rig: Rig) -> None:
    with CameraClient(elphel_rig.camera_url, elphel_rig.token) as cam:
        before = cam.register(RED_GAIN)["value"]
        assert elphel_rig.fault("i2c_nak", port=0) == [{"kind": "i2c_nak", "port": 0, "count": 2}]
        with pytest.raises(CameraHTTPError) as refused:
            cam.register(RED_GAIN)
        body = refused.value.body
        assert refused.value.status == 503 and body["error"] == "i2c", body
        assert (body["bus"], body["address"], body["register"]) == ("port 0", 0x48, RED_GAIN)
        assert "port 0" in body["detail"] and "register 0x2d" in body["detail"]
        assert elphel_rig.faults() == []  # both NAKs were used by the daemon's two tries
        assert cam.register(RED_GAIN)["value"] == before

        # A parameter change is written at a frame sync: the NAK is an error event there.
        errors: list[dict[str, Any]] = []
        listening = threading.Event()

        def follow() -> None:
            for event in cam.events(("frame", "error"), port=0, count=200):
                listening.set()
                if event.type == "error":
                    errors.append(event.data)
                    return

        follower = threading.Thread(target=follow, daemon=True)
        follower.start()
        assert listening.wait(30)
        elphel_rig.fault("i2c_nak", port=0, count=2)
        cam.set_params({"GAINR": 0x20000})
        follower.join(60)
        assert errors and errors[0]["port"] == 0 and errors[0]["error"] == "i2c", errors
        assert "port 0" in errors[0]["detail"] and "register 0x" in errors[0]["detail"]
        elphel_rig.clear_faults()
        assert cam.capture(0).image.size > 0


def test_a_bad_fault_is_refused_with_what_is_allowed(elphel_rig: Rig) -> None:
    with pytest.raises(ValueError, match="port=9; allowed: one of"):
        elphel_rig.fault("i2c_nak", port=9)
    with pytest.raises(ValueError, match="kind"):
        elphel_rig.fault("lightning")
    with pytest.raises(ValueError, match="count"):
        elphel_rig.fault("i2c_nak", count=0)
    with pytest.raises(ValueError, match="port"):
        elphel_rig.fault("motor_stall", port=0)
    assert elphel_rig.faults() == []


def test_stalled_motor_fails_the_move_and_clearing_moves_again(elphel_rig: Rig) -> None:
    with StageClient(elphel_rig.stage_url) as client:
        client.home().wait(120)
        pos = Positioner(client)
        start = pos.read_mm()
        assert elphel_rig.fault("motor_stall") == [{"kind": "motor_stall"}]
        with pytest.raises(StageStallError, match="motor stalled"):
            pos.move_open_loop(start + 2.0)
        assert true_mm(elphel_rig) == pytest.approx(start, abs=0.02)  # it did not move
        elphel_rig.clear_faults()
        assert elphel_rig.faults() == []
        pos.resync_from_caliper()
        moved = pos.move_open_loop(start + 2.0)
        assert moved.caliper_mm == pytest.approx(start + 2.0, abs=0.1)
        assert true_mm(elphel_rig) == pytest.approx(moved.caliper_mm, abs=0.02)


def test_dropped_stage_link_is_a_lost_link_until_cleared(elphel_rig: Rig) -> None:
    with StageClient(elphel_rig.stage_url) as client:
        boot = client.boot_id
        assert client.status() is not None
        assert elphel_rig.fault("stage_link_drop") == [{"kind": "stage_link_drop"}]
        with pytest.raises(StageConnectionError, match="lost"):
            for _ in range(100):  # the cut reaches the client within a command or two
                client.status()
        # The link stays down: a new connection is cut too.
        with pytest.raises((StageConnectionError, StageTimeout)):
            client.reconnect(timeout_s=1.0)
        elphel_rig.clear_faults()
        client.reconnect()
        assert client.boot_id == boot  # the board kept running: same boot, same position
        assert client.status() is not None
