"""A printed checkerboard in the served world: ``elphel-sim up --scenario calib``.

The calibration rig of `elphel_sim.calib_rig` (four cameras, each with its own lens,
residual, blur, rotation and position on Elphel's 150 mm square) stands behind sensor
ports 0..3 of the simulated board, and the board (`PrintedBoard`) is an object of the
world whose pose is set through the simulator's own endpoint (`board_router`):

* ``GET {sim_url}/board`` -- the board's pose and the truth: every camera's lens,
  residual, blur and pose from camera 0, the true pixel of every corner in each camera
  (and whether that camera sees the whole board), and the sensor ``window`` whose pixels
  the lens models describe (a capture with another window sees the board shifted, and
  nothing of it outside that window);
* ``PUT {sim_url}/board`` -- pose the board (``R`` or ``rotation_deg``, ``t_mm``,
  optional ``warp_mm`` and ``blur_px``), in camera 0's frame: ``X0 = R @ Xb + t_mm``;
* ``DELETE {sim_url}/board`` -- take the board away;
* ``GET {sim_url}/board/poses?count=N&seed=S&min_cameras=K`` -- poses that spread the
  board over the cameras' images, tilted, each seen whole by at least K cameras: a
  script puts them one after the other, as a person would move the board.

Each frame records the board's pose at its start, so a frame formed later shows the
board where it was when the frame was taken.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from fastapi import APIRouter, HTTPException
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from elphel_host.calibrate.camera_model import rotation_matrix
from elphel_host.calibrate.pattern import Checkerboard
from elphel_sim.calib_rig import (
    BoardPose,
    CalibRig,
    RigCamera,
    board_poses,
    corner_truth,
    make_rig,
    render_grey,
    whole_board_seen,
)
from elphel_sim.calib_target import PrintedBoard
from elphel_sim.world import World

FloatArray = NDArray[np.float64]

#: The board of the calibration scenarios (docs/calibration.md's example).
CALIB_PATTERN = "checkerboard:9x6:25"
#: Largest extra blur of the board a pose may ask for (sensor px).
MAX_BOARD_BLUR_PX = 8.0


@dataclass(frozen=True)
class BoardState:
    """The board where it is now: its pose and an extra blur (out of focus, moving)."""

    pose: BoardPose
    blur_px: float = 0.0


@dataclass(frozen=True)
class CalibView:
    """What one sensor port sees of the board: its camera and where its lens image lies.

    ``origin`` is the array pixel (left, top) of the lens image's pixel (0, 0): the
    calibration rig's pixels are those of a frame read out with the window at ``origin``
    and of the lens's size.
    """

    camera: RigCamera
    board: PrintedBoard
    origin: tuple[int, int]

    def radiance(self, state: BoardState | None, window: tuple[int, int, int, int]) -> FloatArray:
        """Linear RGB radiance ``(1, height, width, 3)`` of an array ``window`` (left, top, w, h).

        Outside the lens image, and everywhere when ``state`` is None, the background.
        """
        left, top, width, height = window
        lens_window = (left - self.origin[0], top - self.origin[1], width, height)
        if state is None:
            grey = np.full((height, width), self.board.background)
        else:
            grey = render_grey(
                self.camera,
                self.board,
                state.pose,
                window=lens_window,
                extra_blur_px=state.blur_px,
            )
            grey = np.where(_inside_lens(self.camera, lens_window), grey, self.board.background)
        out: FloatArray = (grey[..., None] * np.asarray(self.board.colour))[None]
        return out


def _inside_lens(cam: RigCamera, window: tuple[int, int, int, int]) -> NDArray[np.bool_]:
    left, top, width, height = window
    xs = np.arange(left, left + width)[None, :]
    ys = np.arange(top, top + height)[:, None]
    inside: NDArray[np.bool_] = (
        (xs >= 0) & (xs < cam.lens.width) & (ys >= 0) & (ys < cam.lens.height)
    )
    return inside


@dataclass(frozen=True)
class CalibScene:
    """The calibration rig behind ports 0.., its board and the window its lenses describe.

    ``window`` holds the WOI_* parameters of that window; ``clear`` is the array pixel of
    WOI_LEFT = WOI_TOP = 0 (the sensor's clear-area origin).
    """

    rig: CalibRig
    board: PrintedBoard
    window: dict[str, int]
    clear: tuple[int, int]

    def view(self, port: int) -> CalibView:
        origin = (
            self.clear[0] + self.window["WOI_LEFT"],
            self.clear[1] + self.window["WOI_TOP"],
        )
        return CalibView(self.rig.cameras[port], self.board, origin)


def calib_scene(
    width: int,
    height: int,
    *,
    active: tuple[int, int],
    clear: tuple[int, int],
    seed: int,
) -> CalibScene:
    """A quad rig of ``width`` x ``height`` lenses centred on a sensor's ``active`` area."""
    rig = make_rig(width, height, cameras=4, seed=seed)
    window = {
        "WOI_LEFT": (active[0] - width) // 4 * 2,  # even: the Bayer phase stays
        "WOI_TOP": (active[1] - height) // 4 * 2,
        "WOI_WIDTH": width,
        "WOI_HEIGHT": height,
    }
    return CalibScene(rig, PrintedBoard(Checkerboard.parse(CALIB_PATTERN)), window, clear)


class BoardPoseIn(BaseModel):
    """A pose for the board: ``R`` (3 x 3) or ``rotation_deg`` (a rotation vector), ``t_mm``."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    R: list[list[float]] | None = None
    rotation_deg: list[float] | None = Field(None, min_length=3, max_length=3)
    t_mm: list[float] = Field(min_length=3, max_length=3)
    warp_mm: list[float] = Field([0.0, 0.0], min_length=2, max_length=2)
    blur_px: float = Field(0.0, ge=0.0, le=MAX_BOARD_BLUR_PX)

    def state(self) -> BoardState:
        """The board's state; ValueError names what is wrong."""
        if (self.R is None) == (self.rotation_deg is None):
            raise ValueError("give the board's rotation as R (3x3) or rotation_deg, not both")
        if self.R is not None:
            r = np.asarray(self.R, dtype=np.float64)
            if r.shape != (3, 3) or not np.allclose(r.T @ r, np.eye(3), atol=1e-6):
                raise ValueError(f"R={self.R}; allowed: a 3x3 rotation matrix")
        else:
            r = rotation_matrix(np.radians(np.asarray(self.rotation_deg, dtype=np.float64)))
        t = np.asarray(self.t_mm, dtype=np.float64)
        if not np.all(np.isfinite(t)) or t[2] <= 0:
            raise ValueError(f"t_mm={self.t_mm}; allowed: finite, z > 0 (in front of camera 0)")
        warp = (float(self.warp_mm[0]), float(self.warp_mm[1]))
        return BoardState(BoardPose(r, t, warp), float(self.blur_px))


def pose_json(state: BoardState) -> dict[str, Any]:
    """A board state as `BoardPoseIn` takes it (``R``, ``t_mm``, ``warp_mm``, ``blur_px``)."""
    return {
        "R": state.pose.R.tolist(),
        "t_mm": state.pose.t_mm.tolist(),
        "warp_mm": list(state.pose.warp_mm),
        "blur_px": state.blur_px,
    }


def board_truth(scene: CalibScene, state: BoardState | None) -> dict[str, Any]:
    """``GET {sim_url}/board``: the pose, every camera's truth and the corners it sees."""
    rig, board = scene.rig, scene.board
    corners = None if state is None else corner_truth(rig, board, state.pose)
    whole = (
        [False] * len(rig.cameras) if state is None else whole_board_seen(rig, board, state.pose)
    )
    cameras = []
    for port, cam in enumerate(rig.cameras):
        cameras.append(
            {
                "port": port,
                **cam.lens.to_json(),
                "R": cam.R.tolist(),
                "t_mm": cam.t_mm.tolist(),
                "residual_terms": [list(t) for t in cam.residual.terms],
                "blur_px": [cam.blur_centre_px, cam.blur_edge_px],
                "whole_board": whole[port],
                "corners": None if corners is None else corners[port].tolist(),
            }
        )
    return {
        "pattern": board.pattern.spec,
        "window": dict(scene.window),
        "bayer": rig.bayer,
        "pose": None if state is None else pose_json(state),
        "cameras": cameras,
    }


def board_router(world: World, scene: CalibScene) -> APIRouter:
    """``/board`` (GET, PUT, DELETE) and ``/board/poses``: see the module's notes.

    ``world`` is the served `elphel_sim.world.World`, whose ``board`` the frames record.
    """
    router = APIRouter()

    @router.get("/board")
    def get_board() -> dict[str, Any]:
        """The board's pose (null: no board in view) and the truth of what each camera sees."""
        return board_truth(scene, world.board)

    @router.put("/board")
    def put_board(body: BoardPoseIn) -> dict[str, Any]:
        """Pose the board in camera 0's frame; the next frames show it there."""
        try:
            world.board = body.state()
        except ValueError as e:
            raise HTTPException(status_code=422, detail=str(e)) from e
        return board_truth(scene, world.board)

    @router.delete("/board")
    def delete_board() -> dict[str, Any]:
        """Take the board out of view."""
        world.board = None
        return board_truth(scene, None)

    @router.get("/board/poses")
    def suggested_poses(count: int = 12, seed: int = 0, min_cameras: int = 1) -> dict[str, Any]:
        """``count`` poses spread over the cameras' images, tilted by up to 35 degrees."""
        if not 1 <= count <= 200:
            raise HTTPException(status_code=422, detail=f"count={count}; allowed: 1..200")
        if not 1 <= min_cameras <= len(scene.rig.cameras):
            raise HTTPException(
                status_code=422,
                detail=f"min_cameras={min_cameras}; allowed: 1..{len(scene.rig.cameras)}",
            )
        try:
            poses = board_poses(scene.rig, scene.board, count, seed=seed, min_cameras=min_cameras)
        except ValueError as e:
            raise HTTPException(status_code=422, detail=str(e)) from e
        return {"poses": [pose_json(BoardState(p)) for p in poses]}

    return router
