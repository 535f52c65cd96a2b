"""`elphel calibrate capture` against the calibration rig, the board posed by a script.

The script puts the simulator's board (``{sim_url}/board``) where a person would hold
it, the capture keeps or refuses each view saying why, a second run continues the same
directory, and `elphel calibrate solve` calibrates from what was kept.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from elphel_host.calibrate.capture import (
    Attempt,
    CaptureSession,
    QuadCamera,
    SingleCamera,
    capture_views,
    open_session,
)
from elphel_host.calibrate.guide import CaptureLimits, placement
from elphel_host.calibrate.pattern import Checkerboard
from elphel_host.camera.backends import connect
from elphel_host.cli import main as elphel_main
from elphel_sim.pytest_plugin import Rig

pytestmark = pytest.mark.slow


def _board(rig: Rig, pose: dict[str, Any]) -> dict[str, Any]:
    """Pose the board; the truth."""
    r = httpx.put(f"{rig.sim_url}/board", json=pose, timeout=30)
    r.raise_for_status()
    truth: dict[str, Any] = r.json()
    return truth


def _new_pose(rig: Rig, session: CaptureSession, candidates: list[dict[str, Any]]) -> None:
    """Pose the board at the first candidate whose true placement no kept view has, and
    large enough to be kept."""
    for pose in candidates:
        corners = np.asarray(_board(rig, pose)["cameras"][0]["corners"])
        where = placement(corners, session.pattern, (640, 480))
        new = all(where.distance(p) > 1.5 for v in session.views if (p := v.placements[0]))
        if new and where.area_percent > CaptureLimits().min_area_percent:
            return
    raise AssertionError("no candidate pose is new; give more")


def _poses(rig: Rig, count: int, seed: int, min_cameras: int) -> list[dict[str, Any]]:
    params = {"count": count, "seed": seed, "min_cameras": min_cameras}
    poses: list[dict[str, Any]] = httpx.get(
        f"{rig.sim_url}/board/poses", params=params, timeout=30
    ).json()["poses"]
    return poses


def _small_window(rig: Rig) -> dict[str, Any]:
    truth: dict[str, Any] = httpx.get(f"{rig.sim_url}/board", timeout=30).json()
    with connect(rig.camera_url, rig.token) as camera:
        for port in range(4):
            camera.set_params(truth["window"], port=port)
    return truth


def _moved(pose: dict[str, Any], *, scale: float = 1.0, dx_mm: float = 0.0) -> dict[str, Any]:
    t = np.asarray(pose["t_mm"]) * scale + np.array([dx_mm, 0.0, 0.0])
    return {**pose, "t_mm": t.tolist()}


def _half_out(rig: Rig, pose: dict[str, Any]) -> dict[str, Any]:
    """``pose`` moved along the board's x until half its corners leave camera 0's image."""
    for dx_mm in np.arange(10.0, 3000.0, 10.0):
        moved = _moved(pose, dx_mm=dx_mm)
        xs = np.asarray(_board(rig, moved)["cameras"][0]["corners"])[:, 0]
        if not 0 <= np.median(xs) <= 639:
            return moved
    raise AssertionError("the board never left camera 0's image")


@pytest.mark.elphel_rig(scenario="calib-small", seed=2)
def test_a_scripted_board_is_captured_judged_resumed_and_solved(
    elphel_rig: Rig, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth = _small_window(elphel_rig)
    poses = _poses(elphel_rig, 12, 3, 4)
    plan = [
        {**poses[0], "blur_px": 3.0},  # moving or out of focus
        _half_out(elphel_rig, poses[0]),  # half out of camera 0's image
        _moved(poses[1], scale=2.5),  # far away
        poses[0],
        poses[0],  # the same view again
        *poses[1:5],
    ]
    views = tmp_path / "views"
    session = open_session(views, Checkerboard.parse(truth["pattern"]), cameras=1)
    with connect(elphel_rig.camera_url, elphel_rig.token, timeout_s=60) as camera:
        done = capture_views(
            SingleCamera(camera, 0),
            session,
            views=len(plan),
            attempts=len(plan),
            before=lambda n: _board(elphel_rig, plan[n]),
        )
    statuses = [a.seen[0].status for a in done]
    assert statuses[:5] == ["blurred", "partial", "small", "ok", "ok"]
    assert [a.kept is not None for a in done[:5]] == [False, False, False, True, False]
    assert "blurred" in done[0].reason and "partly seen" in done[1].reason
    assert "too small" in done[2].reason and f"like {done[3].kept}" in done[4].reason
    kept = [a.kept for a in done if a.kept]
    assert sorted(p.name for p in views.glob("view*.tif")) == sorted(kept)
    assert (views / "capture" / "coverage.png").is_file()

    # a second run continues the directory: one more view, through the command line
    _new_pose(elphel_rig, session, poses[5:])
    code = elphel_main(
        [
            "calibrate",
            "capture",
            "--camera",
            elphel_rig.camera_url,
            "--token",
            str(elphel_rig.token),
            "--pattern",
            truth["pattern"],
            "--out",
            str(views),
            "--views",
            str(len(kept) + 1),
            "--attempts",
            "1",
            "--json",
        ]
    )
    out, err = capsys.readouterr()
    assert code == 0, err
    result = json.loads(out)
    assert result["views"] == len(kept) + 1 and result["kept"] == 1 and result["attempts"] == 1, (
        result["not_kept"]
    )
    assert "views per cell" in err and result["hints"]  # six views leave corners to cover

    calib = tmp_path / "calib"
    solve = ["calibrate", "solve", str(views), "--pattern", truth["pattern"], "--out", str(calib)]
    code = elphel_main([*solve, "--json", "--no-cross-validation"])
    out, err = capsys.readouterr()
    assert code == 0, err
    solved = json.loads((calib / "calibration.json").read_text())["cameras"][0]
    assert json.loads(out)["rms_px"] < 0.05
    assert solved["fx"] == pytest.approx(truth["cameras"][0]["fx"], rel=0.01)


@pytest.mark.elphel_rig(scenario="calib-small", seed=4)
def test_a_quad_view_is_one_trigger_of_four_cameras(elphel_rig: Rig, tmp_path: Path) -> None:
    pattern = _small_window(elphel_rig)["pattern"]
    (pose,) = _poses(elphel_rig, 1, 7, 4)
    truth = _board(elphel_rig, pose)
    session = open_session(tmp_path / "views", Checkerboard.parse(pattern), cameras=4)
    with connect(elphel_rig.camera_url, elphel_rig.token, timeout_s=60) as camera:
        done: list[Attempt] = capture_views(QuadCamera(camera), session, views=1)
    assert len(done) == 1 and done[0].kept == "view000"
    assert (tmp_path / "views" / "view000" / "quad.json").is_file()
    assert session.views[0].seen_by == [0, 1, 2, 3]
    for cam, corners in enumerate(session.views[0].corners):
        assert corners is not None
        error = corners - np.asarray(truth["cameras"][cam]["corners"])
        assert np.nanmax(np.abs(error)) == pytest.approx(0.0, abs=0.1)
