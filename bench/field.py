"""Field ("lazy eye") calibration benchmark: simulated drifts found again from scenes.

The calibration rig of `elphel-sim calib-views` (four cameras with their own
rational-model lenses, focal lengths within 1 % and rotations of about 0.4 degrees on a
150 mm square; GRBG Bayer, noise of a 12-bit sensor) with its true calibration; its
cameras 1-3 then drift: each correction (tilt, azimuth, roll, zoom) by ``--drift-px``
(0.3..PX px at the image's centre or corner, random sign, `elphel_sim.calib_scene.
random_drift_px`). ``--scenes`` of the quad's standard scene (background at infinity,
planes at 0.37, 2.5 and 5.2 px, a slanted plane) are rendered through the drifted cameras,
and `refine_extrinsics` refines the calibration from them. Reported per drift: the
misalignment against the truth (`elphel_sim.calib_scene.misalignment_px`: where the
calibration puts cameras 1-3's tiles of points at infinity against where the drifted
cameras see them; px RMS per camera) before, after the full refinement and after a single
update without re-measuring (the peer: one linearised solve, as without iterations), the
mismatch the command reports, the updates made and the seconds of the refinement
(rendering not timed). Prints one JSON object; nothing is hard-coded.

    .venv/bin/python bench/field.py [--width 640 --height 480 --scenes 2 --drift-px 0.3 1 5]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from typing import Any

import numpy as np

from elphel_host.calibrate.field import refine_extrinsics
from elphel_host.tp.calibrated import CalibratedGeometry
from elphel_host.tp.images import QuadImages
from elphel_sim.calib_rig import CalibRig, make_rig
from elphel_sim.calib_scene import (
    drifted_rig,
    misalignment_px,
    random_drift_px,
    rectified_rig,
    render_raw_quad,
)
from elphel_sim.quad import standard_scene


def geometry(rig: CalibRig) -> CalibratedGeometry:
    return CalibratedGeometry.from_cameras([(c.lens, c.R, c.t_mm) for c in rig.cameras])


def one_drift(rig: CalibRig, max_px: float, scenes: int, seed: int) -> dict[str, Any]:
    moved = drifted_rig(rig, random_drift_px(max_px, seed=seed))
    quads = []
    full = float((1 << rig.sensor.bits) - 1)
    for s in range(scenes):
        raw = render_raw_quad(standard_scene(rectified_rig(moved), seed=s), moved, seed=s + 1)
        quads.append(QuadImages((raw / full).astype(np.float32), bayer=rig.bayer))
    cameras = [(c.lens, c.R, c.t_mm) for c in rig.cameras]
    truth = geometry(moved)
    t0 = time.perf_counter()
    ours = refine_extrinsics(quads, cameras)
    seconds = time.perf_counter() - t0
    peer = refine_extrinsics(quads, cameras, iterations=1)
    before = misalignment_px(geometry(rig), truth)
    after = misalignment_px(CalibratedGeometry.from_cameras(ours.cameras), truth)
    single = misalignment_px(CalibratedGeometry.from_cameras(peer.cameras), truth)
    return {
        "drift_px": max_px,
        "misalignment_before_px": before.round(4).tolist(),
        "misalignment_after_px": after.round(4).tolist(),
        "misalignment_one_update_px": single.round(4).tolist(),
        "after_over_one_update": round(float(after.max() / single.max()), 3),
        "after_over_before": round(float(after.max() / before.max()), 5),
        "reported_mismatch_before_px": ours.mismatch_before_px.round(4).tolist(),
        "reported_mismatch_after_px": ours.mismatch_after_px.round(5).tolist(),
        "scatter_px": round(ours.scatter_px, 4),
        "updates": ours.iterations,
        "tiles": ours.tiles,
        "infinity_tiles": ours.infinity_tiles,
        "seconds": round(seconds, 2),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--scenes", type=int, default=2)
    p.add_argument("--drift-px", type=float, nargs="+", default=[0.3, 1.0, 5.0])
    p.add_argument("--seed", type=int, default=4, help="seed of the drifts")
    args = p.parse_args()
    rig = make_rig(args.width, args.height, seed=0)
    cases = [one_drift(rig, d, args.scenes, args.seed) for d in args.drift_px]
    result = {
        "benchmark": "field",
        "image": f"{args.width}x{args.height}",
        "scenes": args.scenes,
        "peer": "one update without re-measuring",
        "cases": cases,
        "machine": platform.machine(),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
