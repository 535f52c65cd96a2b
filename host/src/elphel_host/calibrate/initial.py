"""A first guess for the bundle adjustment: each camera alone, then the rig from shared views.

Each camera is calibrated alone by OpenCV's ``calibrateCamera`` (five distortion
coefficients; the rational model's three more start at zero), which also gives the
board's pose in that camera for each of its views. Cameras are then placed relative to
camera 0 along the views they share (breadth first through cameras linked by shared
views; the rotations averaged by their chordal mean, the translations by the median),
and each view's board is placed in camera 0's frame through any camera that saw it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elphel_host.calibrate.camera_model import CameraModel, rotation_matrix, rotation_vector
from elphel_host.calibrate.observations import CalibrationInputError, Observations

FloatArray = NDArray[np.float64]
#: A camera whose boards are all tilted less than this is refused (its focal length is unknowable).
MIN_TILT_DEG = 10.0
Pose = tuple[FloatArray, FloatArray]  # (R, t): x_to = R @ x_from + t


@dataclass(frozen=True)
class InitialGuess:
    """Intrinsics per camera, each camera's pose from camera 0, each board's pose in camera 0."""

    lenses: tuple[CameraModel, ...]
    rig: tuple[Pose, ...]
    boards: tuple[Pose, ...]


def _compose(a: Pose, b: Pose) -> Pose:
    """``a`` after ``b``."""
    return a[0] @ b[0], a[0] @ b[1] + a[1]


def _inverse(a: Pose) -> Pose:
    return a[0].T, -a[0].T @ a[1]


def _mean_pose(poses: list[Pose]) -> Pose:
    u, _, vt = np.linalg.svd(sum(p[0] for p in poses))
    rot = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return rot, np.median(np.array([p[1] for p in poses]), axis=0)


def _check_tilts(camera: int, rvecs: Sequence[NDArray[Any]]) -> None:
    tilts = [
        np.degrees(np.arccos(min(1.0, abs(rotation_matrix(np.ravel(r))[2, 2])))) for r in rvecs
    ]
    if max(tilts) < MIN_TILT_DEG:
        raise CalibrationInputError(
            f"camera {camera}: every view shows the board nearly parallel to the sensor (largest "
            f"tilt {max(tilts):.1f} deg; allowed: some views tilted by {MIN_TILT_DEG:g} deg or "
            "more): add views with the board turned by 20-40 deg about its horizontal and its "
            "vertical axis"
        )


def _single_camera(obs: Observations, camera: int) -> tuple[CameraModel, dict[int, Pose]]:
    obj, img, views = [], [], []
    for v in obs.seen(camera):
        found = obs.corners[v][camera]
        assert found is not None
        ok = np.isfinite(found.pixels).all(axis=1)
        obj.append(obs.pattern.object_points_mm()[ok].astype(np.float32))
        img.append(found.pixels[ok].astype(np.float32))
        views.append(v)
    size = obs.sizes[camera]
    rms, k, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, size, None, None)
    _check_tilts(camera, rvecs)
    if not np.isfinite(rms) or rms > 5.0:
        raise CalibrationInputError(
            f"camera {camera}: its first single-camera fit leaves {rms:.2f} px; allowed: a few "
            "tenths: check the pattern SPEC and that every view shows the same board"
        )
    d = np.zeros(8)
    d[:5] = np.ravel(dist)[:5]
    lens = CameraModel(
        size[0], size[1], k[0, 0], k[1, 1], k[0, 2], k[1, 2], tuple(float(c) for c in d)
    )
    poses = {
        v: (rotation_matrix(np.ravel(r)), np.ravel(t).astype(np.float64))
        for v, r, t in zip(views, rvecs, tvecs, strict=True)
    }
    return lens, poses


def _place_cameras(obs: Observations, seen: list[dict[int, Pose]]) -> list[Pose]:
    """Each camera's pose from camera 0, breadth first through shared views."""
    placed: dict[int, Pose] = {0: (np.eye(3), np.zeros(3))}
    frontier = [0]
    while frontier:
        a = frontier.pop(0)
        for b in range(obs.cameras):
            shared = sorted(set(seen[a]) & set(seen[b]))
            if b in placed or not shared:
                continue
            # camera a's frame -> camera b's frame, through each shared board
            rel = [_compose(seen[b][v], _inverse(seen[a][v])) for v in shared]
            placed[b] = _compose(_mean_pose(rel), placed[a])
            frontier.append(b)
    return [placed[c] for c in range(obs.cameras)]


def initial_guess(obs: Observations) -> InitialGuess:
    """The first guess (the observations must have passed `check_observations`)."""
    fits = [_single_camera(obs, c) for c in range(obs.cameras)]
    seen = [poses for _, poses in fits]
    rig = _place_cameras(obs, seen)
    boards = []
    for v in range(len(obs.corners)):
        c = next(c for c in range(obs.cameras) if v in seen[c])
        boards.append(_compose(_inverse(rig[c]), seen[c][v]))
    return InitialGuess(tuple(lens for lens, _ in fits), tuple(rig), tuple(boards))


def pose_vector(pose: Pose) -> FloatArray:
    """``(6,)``: rotation vector then translation."""
    return np.concatenate([rotation_vector(pose[0]), pose[1]])
