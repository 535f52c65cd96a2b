"""Faults on the simulated stage: each gets a defined error; nothing unverified is believed."""

from __future__ import annotations

import random

import pytest

from elphel_host.errors import (
    StageCaliperError,
    StageCommandError,
    StageConnectionError,
    StageError,
    StageLimitError,
    StageProtocolError,
    StageResetError,
    StageStallError,
    StageTimeout,
)
from elphel_host.stage import Positioner, StageClient
from elphel_sim.stage_server import SimStage


def caliper_truth(sim: SimStage) -> float:
    s = sim.sim_state()
    return s["true_mm"] - s["caliper_zero_mm"]


@pytest.fixture
def homed():
    with SimStage(seed=5, time_scale=100) as sim:
        sim.wait_booted()
        client = StageClient(sim.tcp_url)
        try:
            client.home().wait(30)
            yield sim, client, Positioner(client)
        finally:
            client.close()


def test_defined_errors(homed):
    sim, client, pos = homed
    with pytest.raises(StageCommandError, match="unknown command 'FLY'") as e:
        client.command("FLY")
    assert e.value.code == 1
    with pytest.raises(StageLimitError, match="outside soft limits"):
        client.move_to_steps(10**6)
    with pytest.raises(StageLimitError):
        pos.move_open_loop(500.0)
    sim.sim_caliper_glitch(12, "short")
    with pytest.raises(StageCaliperError, match=r"error 2[12]"):
        client.read_caliper_um()
    sim.caliper.glitches.clear()
    client.caliper_power(False)
    with pytest.raises(StageCaliperError, match="power is off"):
        client.read_caliper_um()
    client.caliper_power(True)
    sim.sim_stall(True)
    with pytest.raises(StageStallError, match="motor stalled"):
        pos.move_open_loop(caliper_truth(sim) + 5.0)
    sim.sim_stall(False)
    steps = pos.resync_from_caliper()
    assert client.status().steps == steps
    assert abs(pos.move_open_loop(20.0).caliper_mm - caliper_truth(sim)) <= 0.011


def test_drop_mid_move_then_reconnect(homed):
    sim, client, pos = homed
    pos.move_open_loop(10.0)
    handle = client.move_to_steps(client.status().steps + 3000)
    sim.sim_drop_connection()
    with pytest.raises(StageConnectionError):
        handle.wait(10)
    client.reconnect()
    final = handle.wait(30)  # the board kept moving; same boot id
    assert final.steps == handle.target_steps
    assert abs(pos.read_mm() - caliper_truth(sim)) <= 0.011


def test_reset_is_detected_and_resynced_from_caliper(homed):
    sim, client, pos = homed
    pos.move_open_loop(30.0)
    sim.sim_reset()
    with pytest.raises((StageResetError, StageConnectionError, StageTimeout, StageProtocolError)):
        for _ in range(200):
            client.status()
    for _ in range(5):  # the board may still be booting: a timeout, then the new boot id
        try:
            client.reconnect()
        except StageTimeout:
            continue
        except StageResetError:
            break
    else:
        pytest.fail("reconnect never reported the reset")
    assert not client.status().homed
    pos.resync_from_caliper()
    assert client.status().homed
    r = pos.move_closed_loop(31.0)
    assert abs(caliper_truth(sim) - 31.0) <= 0.01 and abs(r.caliper_mm - 31.0) <= 0.011


def test_pty_link(homed):
    sim, _client, _pos = homed
    assert sim.pty_path is not None
    with StageClient(sim.pty_path) as over_pty:
        assert over_pty.identify().model == "esp8266-stage"
        assert abs(over_pty.read_caliper_um() / 1000 - caliper_truth(sim)) <= 0.011


def test_fault_run_1000_commands():
    rng = random.Random(99)
    counts = {
        "commands": 0,
        "garbled_errors": 0,
        "drops": 0,
        "reconnects": 0,
        "stalls": 0,
        "stall_errors": 0,
        "limit_refusals": 0,
        "timeouts": 0,
        "resyncs": 0,
        "positions": 0,
        "unconfirmed": 0,
    }
    with SimStage(seed=17, time_scale=100) as sim:
        sim.wait_booted()
        client = StageClient(sim.tcp_url, retries=6, reply_timeout_s=0.5)
        try:
            client.home().wait(30)
            pos = Positioner(client)
            stalled = False
            for i in range(1000):
                counts["commands"] += 1
                sim.sim_garble(0.003 if (i // 50) % 2 else 0.0)
                if rng.random() < 0.03:
                    sim.sim_drop_connection()
                    counts["drops"] += 1
                if not stalled and rng.random() < 0.02:
                    sim.sim_stall(True)
                    stalled = True
                    counts["stalls"] += 1
                op = rng.random()
                try:
                    if op < 0.25:
                        client.status()
                    elif op < 0.45:
                        mm = pos.read_mm()
                        counts["positions"] += 1
                        counts["unconfirmed"] += abs(mm - caliper_truth(sim)) > 0.011
                    elif op < 0.75:
                        here = caliper_truth(sim)
                        target = min(110.0, max(5.0, here + rng.uniform(-3.0, 3.0)))
                        r = pos.move_open_loop(target)
                        counts["positions"] += 1
                        counts["unconfirmed"] += abs(r.caliper_mm - caliper_truth(sim)) > 0.011
                    elif op < 0.85:
                        with pytest.raises(StageLimitError):
                            pos.move_open_loop(rng.choice([-5.0, 130.0, 500.0]))
                        counts["limit_refusals"] += 1
                    elif op < 0.95:
                        client.limits_steps()
                    else:
                        client.stop()
                except StageStallError:
                    counts["stall_errors"] += 1
                    sim.sim_stall(False)
                    stalled = False
                    pos.resync_from_caliper()
                    counts["resyncs"] += 1
                except StageConnectionError:
                    sim.sim_garble(0.0)
                    client.reconnect()
                    counts["reconnects"] += 1
                except (StageProtocolError, StageTimeout):
                    counts["garbled_errors"] += 1
                except StageResetError:
                    pos.resync_from_caliper()
                    counts["resyncs"] += 1
                except StageError as e:
                    # Damage the retries could not hide (e.g. a move refused as busy) is an
                    # error the caller sees; the stage must still be consistent afterwards.
                    counts.setdefault(type(e).__name__, 0)
                    counts[type(e).__name__] += 1
                    if isinstance(e, StageCommandError) and e.code == 8:
                        client.stop()
            sim.sim_garble(0.0)
            sim.sim_stall(False)
            assert client.status().state in ("IDLE", "RUN")  # connected again
            truth = sim.sim_state()
        finally:
            client.close()
    print(
        "fault run:",
        counts,
        "end stops:",
        truth["end_stop_hits"],
        "range seen:",
        round(truth["min_mm_seen"], 3),
        round(truth["max_mm_seen"], 3),
    )
    assert counts["unconfirmed"] == 0
    assert truth["end_stop_hits"] == 0
    assert truth["max_mm_seen"] < sim.mech_cfg.lim_max_mm  # max switch never reached
    assert counts["drops"] > 10 and counts["stalls"] > 5 and counts["stall_errors"] > 0
    assert counts["positions"] > 300
