"""Calibration benchmark: corners, intrinsics, rig and time against OpenCV on the same images.

Renders a simulated quad (`elphel_sim.calib_rig`: four cameras, each with its own
rational-model lens, focal length, principal point and ~0.4 degree rotation on a 150 mm
square; space-variant blur 0.7-1.1 px; GRBG Bayer; shot and read noise of a 12-bit
sensor) looking at a 9x6 checkerboard of 25 mm squares in ``--views`` poses, each seen
whole by at least two cameras. Then on the same images:

- ours: `detect` on every image, then `calibrate` (one bundle adjustment of all cameras);
- OpenCV: ``findChessboardCornersSB`` (CALIB_CB_ACCURACY) on the same grey images (its
  corners put in the board's order by the nearest true corner, as OpenCV's order may
  start at any corner of the board), then
  ``calibrateCamera`` with CALIB_RATIONAL_MODEL per camera and ``stereoCalibrate``
  (CALIB_FIX_INTRINSIC | CALIB_RATIONAL_MODEL: without the second flag it keeps only 5
  of the 8 coefficients) of each camera with camera 0.

Reported: corner RMS error against the truth (px, both, and their ratio); per camera the
projection difference to the true lens after the implied rotation (mrcal's measure, px
RMS over the image less a 5 % border); the rig's rotation error (urad, after each
camera's implied rotation, and in px at the focal length) and translation error (mm);
the seconds of detection plus solve, and their ratio. Rendering is not timed. Then the
predicted projection uncertainty against its Monte Carlo spread (``--monte-carlo``
re-draws of Gaussian corner noise at our measured corner error). With ``--residual-px``
each lens also carries a smooth non-radial error the rational model cannot follow, and
``residual_grid_fit`` says whether the solve kept its residual grids. Prints one JSON
object; nothing is hard-coded.

    .venv/bin/python bench/calibrate.py [--width 1296 --height 968 --views 24 --seed 0]
                                        [--residual-px 0.2]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from typing import Any

import cv2
import numpy as np

from elphel_host.calibrate.camera_model import CameraModel, rotation_vector
from elphel_host.calibrate.detect import Corners, detect, grey_image
from elphel_host.calibrate.observations import Observations
from elphel_host.calibrate.pattern import Checkerboard
from elphel_host.calibrate.quality import implied_rotation, projection_difference
from elphel_host.calibrate.solve import MARGIN, calibrate
from elphel_sim.calib_rig import (
    BoardPose,
    CalibRig,
    board_poses,
    corner_truth,
    make_rig,
    render_view,
)
from elphel_sim.calib_target import PrintedBoard

PATTERN = Checkerboard(9, 6, 25.0)


class TrueLens:
    """A simulated camera's lens (rational model and residual) as projection_difference wants."""

    def __init__(self, cam: Any) -> None:
        self.cam = cam
        self.width, self.height = cam.lens.width, cam.lens.height

    def project(self, points: np.ndarray) -> np.ndarray:
        q = self.cam.lens.project(points)
        return q + self.cam.residual.at(q)

    def rays(self, pixels: np.ndarray, *, strict: bool = True) -> np.ndarray:
        return self.cam.lens.rays(self.cam.model_pixels(pixels), strict=strict)


def render(
    rig: CalibRig, board: PrintedBoard, poses: list[BoardPose], seed: int
) -> tuple[list, list]:
    images, truths = [], []
    for k, pose in enumerate(poses):
        images.append(render_view(rig, board, pose, seed=seed + k))
        truths.append(corner_truth(rig, board, pose))
    return images, truths


def ours(images: list, rig: CalibRig) -> tuple[Observations, float, float, Any]:
    t0 = time.perf_counter()
    rows = tuple(tuple(detect(im, PATTERN, bayer=rig.bayer) for im in view) for view in images)
    t1 = time.perf_counter()
    obs = Observations(
        PATTERN,
        (rig.size,) * len(rig.cameras),
        rows,
        tuple(f"view{k:03d}" for k in range(len(rows))),
    )
    cal = calibrate(obs, cross_validate=False)
    t2 = time.perf_counter()
    return obs, t1 - t0, t2 - t1, cal


def _sb(image: np.ndarray, bayer: str | None, truth: np.ndarray) -> np.ndarray | None:
    grey = grey_image(image, bayer)
    lo, hi = np.percentile(grey, (0.5, 99.5))
    eight = np.clip((grey - lo) * 255 / (hi - lo), 0, 255).astype(np.uint8)
    found, corners = cv2.findChessboardCornersSB(
        eight, (PATTERN.cols, PATTERN.rows), flags=cv2.CALIB_CB_ACCURACY
    )
    if not found:
        return None
    c = corners.reshape(-1, 2).astype(np.float64)
    # OpenCV's order may start at any corner of the board: put its corners in the board's
    # order by the nearest true corner (a view whose corners do not pair off is dropped)
    order = np.argmin(np.linalg.norm(truth[:, None] - c[None], axis=-1), axis=1)
    if len(set(order.tolist())) != len(c):
        return None
    return c[order]


def opencv(images: list, truths: list, rig: CalibRig) -> dict[str, Any]:
    n_cam = len(rig.cameras)
    t0 = time.perf_counter()
    found = [
        [_sb(im, rig.bayer, tr) for im, tr in zip(view, truth, strict=True)]
        for view, truth in zip(images, truths, strict=True)
    ]
    t1 = time.perf_counter()
    obj = PATTERN.object_points_mm().astype(np.float32)
    models, poses = [], []
    for c in range(n_cam):
        views = [v for v in range(len(images)) if found[v][c] is not None]
        img = [found[v][c].astype(np.float32) for v in views]
        _, k, d, rv, tv = cv2.calibrateCamera(
            [obj] * len(views), img, rig.size, None, None, flags=cv2.CALIB_RATIONAL_MODEL
        )
        models.append((k, d))
        poses.append(dict(zip(views, zip(rv, tv, strict=True), strict=True)))
    rig_out = [(np.eye(3), np.zeros(3))]
    for c in range(1, n_cam):
        shared = [
            v for v in range(len(images)) if found[v][0] is not None and found[v][c] is not None
        ]
        out = cv2.stereoCalibrate(
            [obj] * len(shared),
            [found[v][0].astype(np.float32) for v in shared],
            [found[v][c].astype(np.float32) for v in shared],
            models[0][0],
            models[0][1],
            models[c][0],
            models[c][1],
            rig.size,
            flags=cv2.CALIB_FIX_INTRINSIC | cv2.CALIB_RATIONAL_MODEL,
        )
        rig_out.append((out[5], out[6].ravel()))
    t2 = time.perf_counter()
    lenses = [
        CameraModel(
            rig.size[0],
            rig.size[1],
            k[0, 0],
            k[1, 1],
            k[0, 2],
            k[1, 2],
            tuple(float(x) for x in np.ravel(d)[:8]),
        )
        for k, d in models
    ]
    return {
        "found": found,
        "lenses": lenses,
        "rig": rig_out,
        "detect_s": t1 - t0,
        "solve_s": t2 - t1,
    }


def corner_rms(found: list, truths: list) -> float:
    errs = [
        (f.pixels if isinstance(f, Corners) else f) - t
        for fv, tv in zip(found, truths, strict=True)
        for f, t in zip(fv, tv, strict=True)
        if f is not None
    ]
    e = np.concatenate(errs)
    return float(np.sqrt(np.nanmean(np.sum(e**2, axis=1))))


def rig_errors(lenses: list, rig_est: list, rig: CalibRig) -> list[dict[str, float]]:
    turn = [
        implied_rotation(m, TrueLens(c), margin=MARGIN)
        for m, c in zip(lenses, rig.cameras, strict=True)
    ]
    out = []
    for k in range(1, len(rig.cameras)):
        r, t = rig_est[k]
        err = float(np.linalg.norm(rotation_vector(turn[k] @ r @ turn[0].T @ rig.cameras[k].R.T)))
        out.append(
            {
                "rotation_urad": err * 1e6,
                "rotation_px": err * rig.cameras[k].lens.fx,
                "translation_mm": float(np.abs(np.ravel(t) - rig.cameras[k].t_mm).max()),
            }
        )
    return out


def intrinsics(lenses: list, rig: CalibRig) -> list[float]:
    return [
        float(np.sqrt(np.nanmean(projection_difference(m, TrueLens(c), margin=MARGIN) ** 2)))
        for m, c in zip(lenses, rig.cameras, strict=True)
    ]


def monte_carlo(
    rig: CalibRig,
    board: PrintedBoard,
    poses: list[BoardPose],
    noise_px: float,
    draws: int,
    seed: int,
) -> dict[str, Any]:
    """Re-draw the corner noise ``draws`` times; the spread of the solved projections.

    Each draw adds Gaussian noise of ``noise_px`` to the true corners (the views each
    camera sees whole) and solves; the spread is the RMS over the image (less the 5 %
    border) of each pixel's standard deviation per axis across the draws, after each
    solution's implied rotation to the truth; the prediction is the mean of the solves'
    own `uncertainty_px`.
    """
    from elphel_host.calibrate.quality import pixel_grid
    from elphel_sim.calib_rig import whole_board_seen

    rng = np.random.default_rng(seed)
    truths = [corner_truth(rig, board, p) for p in poses]
    seen = [whole_board_seen(rig, board, p) for p in poses]
    names = tuple(f"view{k:03d}" for k in range(len(poses)))
    landed: list[list[np.ndarray]] = [[] for _ in rig.cameras]
    predicted: list[list[float]] = [[] for _ in rig.cameras]
    for _ in range(draws):
        rows = tuple(
            tuple(
                Corners(
                    t + rng.normal(0, noise_px, t.shape), np.full(len(t), noise_px), np.ones(len(t))
                )
                if ok
                else None
                for t, ok in zip(tv, sv, strict=True)
            )
            for tv, sv in zip(truths, seen, strict=True)
        )
        cal = calibrate(
            Observations(PATTERN, (rig.size,) * len(rig.cameras), rows, names), cross_validate=False
        )
        for c, (res, cam) in enumerate(zip(cal.cameras, rig.cameras, strict=True)):
            pixels = pixel_grid(res.lens.width, res.lens.height, step_px=32.0, margin=MARGIN)
            rays = TrueLens(cam).rays(pixels, strict=False)
            v = (
                np.column_stack([rays, np.ones(len(rays))])
                @ implied_rotation(TrueLens(cam), res.lens, margin=MARGIN).T
            )
            landed[c].append(res.lens.project(v))
            predicted[c].append(res.uncertainty_px)
    out = []
    for c in range(len(rig.cameras)):
        spread = np.std(np.array(landed[c]), axis=0, ddof=1)  # (pixels, 2)
        measured = float(np.sqrt(np.nanmean(spread**2)))
        out.append(
            {
                "measured_px": measured,
                "predicted_px": float(np.mean(predicted[c])),
                "ratio": float(np.mean(predicted[c])) / measured,
            }
        )
    return {"draws": draws, "noise_px": noise_px, "cameras": out}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=1296)
    ap.add_argument("--height", type=int, default=968)
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--monte-carlo", type=int, default=20, metavar="DRAWS", help="noise re-draws (0: skip)"
    )
    ap.add_argument(
        "--residual-px",
        type=float,
        default=0.0,
        metavar="PX",
        help="each lens's smooth non-radial error beyond the rational model (default 0)",
    )
    a = ap.parse_args()
    rig = make_rig(a.width, a.height, seed=a.seed, residual_px=a.residual_px)
    board = PrintedBoard(PATTERN)
    poses = board_poses(rig, board, a.views, seed=a.seed + 1, warp_mm=(0.5, -0.3), min_cameras=2)
    images, truths = render(rig, board, poses, a.seed + 100)
    obs, detect_s, solve_s, cal = ours(images, rig)
    cv = opencv(images, truths, rig)
    our_corners, cv_corners = corner_rms(obs.corners, truths), corner_rms(cv["found"], truths)
    our_intr, cv_intr = (
        intrinsics([c.lens for c in cal.cameras], rig),
        intrinsics(cv["lenses"], rig),
    )
    ours_s, cv_s = detect_s + solve_s, cv["detect_s"] + cv["solve_s"]
    result = {
        "image": [a.width, a.height],
        "cameras": len(rig.cameras),
        "views": a.views,
        "corners_rms_px": {
            "ours": our_corners,
            "opencv_sb": cv_corners,
            "ratio": our_corners / cv_corners,
        },
        "images_found": {
            "ours": sum(f is not None for v in obs.corners for f in v),
            "opencv_sb": sum(f is not None for v in cv["found"] for f in v),
            "of": len(images) * len(rig.cameras),
        },
        "intrinsics_projection_diff_px": {
            "ours": our_intr,
            "opencv_rational": cv_intr,
            "ratio_worst": max(our_intr) / max(cv_intr),
        },
        "rig": {
            "ours": rig_errors(
                [c.lens for c in cal.cameras], [(c.R, c.t_mm) for c in cal.cameras], rig
            ),
            "opencv_stereo": rig_errors(cv["lenses"], cv["rig"], rig),
        },
        "residual_rms_px": cal.rms_px,
        "lens_residual_px": a.residual_px,
        "residual_grid_fit": cal.residual_grid,
        "board_warp_mm": {"solved": list(cal.warp_mm), "true": [0.5, -0.3]},
        "seconds": {
            "ours_detect": detect_s,
            "ours_solve": solve_s,
            "opencv_detect": cv["detect_s"],
            "opencv_calibrate": cv["solve_s"],
            "ratio": ours_s / cv_s,
        },
        "machine": platform.machine(),
    }
    if a.monte_carlo:
        result["uncertainty_monte_carlo"] = monte_carlo(
            rig, board, poses, our_corners / np.sqrt(2), a.monte_carlo, a.seed + 7
        )
    print(json.dumps(result))


if __name__ == "__main__":
    main()
