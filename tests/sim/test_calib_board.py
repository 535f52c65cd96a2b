"""The calibration board as an object of the served world: ``{sim_url}/board``."""

from __future__ import annotations

import io
import json
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import tifffile
from fastapi.testclient import TestClient

from elphel_camd.api import create_app
from elphel_camd.service import CameraService
from elphel_host.calibrate.detect import detect
from elphel_host.calibrate.pattern import Checkerboard
from elphel_sim.board import SimCameraBoard
from elphel_sim.calib_board import BoardState
from elphel_sim.calib_rig import BoardPose, board_poses, corner_truth
from elphel_sim.launcher import create_sim_app
from elphel_sim.scenarios import build

AUTH = {"Authorization": "Bearer t"}
PATTERN = Checkerboard(9, 6, 25.0)
Rig = tuple[SimCameraBoard, TestClient, TestClient]


@pytest.fixture(scope="module")
def rig() -> Iterator[Rig]:
    board = SimCameraBoard(build("calib-small", seed=3), seed=3)
    camera_app = create_app(CameraService(board), token="t", public_reads=True)
    with TestClient(camera_app) as camera, TestClient(create_sim_app(board)) as sim:
        window = sim.get("/board").json()["window"]
        assert camera.patch("/api/v1/ports/0/params", json=window, headers=AUTH).status_code == 200
        board.sim_advance(frames=3, port=0)
        yield board, camera, sim


def _poses(sim: TestClient, count: int, seed: int) -> list[dict[str, Any]]:
    """Poses that every camera sees whole."""
    r = sim.get("/board/poses", params={"count": count, "seed": seed, "min_cameras": 4})
    poses: list[dict[str, Any]] = r.json()["poses"]
    return poses


def _frame(camera: TestClient, frame: int | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    params = {} if frame is None else {"frame": frame}
    r = camera.post("/api/v1/ports/0/capture", params=params, headers=AUTH)
    assert r.status_code == 200, r.text
    with tifffile.TiffFile(io.BytesIO(r.content)) as tif:
        return tif.asarray(), json.loads(tif.pages.first.description)


def test_a_posed_board_is_seen_where_the_truth_puts_its_corners(rig: Rig) -> None:
    _, camera, sim = rig
    (pose,) = _poses(sim, 1, 5)
    truth = sim.put("/board", json=pose).json()
    assert np.allclose(truth["pose"]["R"], pose["R"]) and truth["pattern"] == PATTERN.spec
    image, meta = _frame(camera)
    assert image.shape == (480, 640) and image.max() < 4000  # 12 bits, not clipped
    found = detect(image, PATTERN, bayer=meta["bayer"])
    assert found is not None and truth["cameras"][0]["whole_board"]
    error = found.pixels - np.asarray(truth["cameras"][0]["corners"])
    assert np.sqrt(np.nanmean(error**2)) < 0.03
    lens = truth["cameras"][0]
    assert {"fx", "fy", "cx", "cy", "distortion", "R", "t_mm", "blur_px"} <= set(lens)


def test_a_frame_shows_the_board_where_it_was_when_the_frame_started(rig: Rig) -> None:
    board, camera, sim = rig
    first, second = _poses(sim, 2, 8)
    truth = sim.put("/board", json=first).json()
    board.sim_advance(frames=2, port=0)
    frame = camera.get("/api/v1/ports/0/frame").json()["frame"]
    sim.put("/board", json=second)  # moved before the earlier frame's image is formed
    image, meta = _frame(camera, frame)
    found = detect(image, PATTERN, bayer=meta["bayer"])
    assert found is not None
    error = found.pixels - np.asarray(truth["cameras"][0]["corners"])
    assert np.nanmax(np.abs(error)) < 0.1
    recorded = sim.get(f"/ports/0/frames/{frame}").json()["board"]
    assert np.allclose(recorded["R"], first["R"]) and np.allclose(recorded["t_mm"], first["t_mm"])


def test_an_extra_blur_widens_the_edges(rig: Rig) -> None:
    _, camera, sim = rig
    (pose,) = _poses(sim, 1, 5)
    widths = []
    for blur_px in (0.0, 2.5):
        sim.put("/board", json={**pose, "blur_px": blur_px})
        image, meta = _frame(camera)
        found = detect(image, PATTERN, bayer=meta["bayer"])
        assert found is not None
        widths.append(float(np.nanmedian(found.blur_px)))
    assert widths[0] < 1.1 and widths[1] > 2.3


def test_without_a_board_the_frame_is_the_background(rig: Rig) -> None:
    _, camera, sim = rig
    assert sim.delete("/board").json()["pose"] is None
    image, _ = _frame(camera)
    assert detect(image, PATTERN, bayer="GRBG") is None
    assert image.std() < 0.1 * image.mean()


@pytest.mark.parametrize(
    ("body", "named"),
    [
        ({"t_mm": [0, 0, 500]}, "R (3x3) or rotation_deg"),
        ({"R": np.eye(3).tolist(), "rotation_deg": [0, 0, 0], "t_mm": [0, 0, 500]}, "not both"),
        ({"R": (2 * np.eye(3)).tolist(), "t_mm": [0, 0, 500]}, "a 3x3 rotation matrix"),
        ({"rotation_deg": [0, 0, 0], "t_mm": [0, 0, -5]}, "z > 0"),
    ],
)
def test_a_bad_pose_is_refused_naming_what_is_allowed(
    rig: Rig, body: dict[str, Any], named: str
) -> None:
    _, _, sim = rig
    r = sim.put("/board", json=body)
    assert r.status_code == 422 and named in r.json()["detail"]


def test_unknown_fields_and_bad_requests_are_refused(rig: Rig) -> None:
    _, _, sim = rig
    pose = {"rotation_deg": [10, 0, 0], "t_mm": [0, 0, 500]}
    assert sim.put("/board", json={**pose, "tilt": 3}).status_code == 422
    assert sim.put("/board", json={**pose, "blur_px": 99}).status_code == 422
    r = sim.get("/board/poses", params={"count": 0})
    assert r.status_code == 422 and "1..200" in r.json()["detail"]
    r = sim.get("/board/poses", params={"min_cameras": 5})
    assert r.status_code == 422 and "1..4" in r.json()["detail"]


def test_other_scenarios_have_no_board() -> None:
    board = SimCameraBoard(build("quad", seed=0), seed=0)
    try:
        with TestClient(create_sim_app(board)) as sim:
            assert sim.get("/board").status_code == 404
    finally:
        board.close()


def test_the_full_size_rig_describes_the_default_window() -> None:
    scene = build("calib", seed=1).calib
    assert scene is not None
    assert scene.window == {"WOI_LEFT": 0, "WOI_TOP": 0, "WOI_WIDTH": 2592, "WOI_HEIGHT": 1944}
    assert scene.rig.size == (2592, 1944) and len(scene.rig.cameras) == 4


def test_outside_the_lens_image_is_the_background() -> None:
    scene = build("calib-small", seed=1).calib
    assert scene is not None
    view = scene.view(0)
    pose = board_poses(scene.rig, scene.board, 1, seed=2, min_cameras=4)[0]
    # the board moved left until it straddles the lens image's left edge
    moved = (
        BoardPose(pose.R, pose.t_mm - np.array([dx_mm, 0.0, 0.0]))
        for dx_mm in np.arange(0.0, 3000.0, 10.0)
    )
    state = BoardState(
        next(m for m in moved if np.median(corner_truth(scene.rig, scene.board, m)[0][:, 0]) < 0)
    )
    corners_x = corner_truth(scene.rig, scene.board, state.pose)[0][:, 0]
    assert corners_x.min() < -20 < 20 < corners_x.max()
    left, top = view.origin
    rgb = view.radiance(state, (left - 100, top, 200, 480))
    grey = rgb[0, ..., 1] / scene.board.colour[1]
    assert np.all(grey[:, :100] == scene.board.background)  # the lens model reaches there
    assert grey[:, 100:].min() < 0.2 and grey[:, 100:].max() > 0.8  # black and white squares
