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

With ``--sequence N``, the refinement on the fly of `elphel tp --refine-extrinsics`
instead: N different scenes through the drifted cameras, processed in order, each quad's
DSI made with the calibration the quads before it refined. Reported per drift: the
misalignment of the calibration each quad was processed with, each quad's DSI error
(RMS over the textured tiles inside one plane), the misalignment at the end and the quads
it took to reach 0.02 px; the peer is `elphel calibrate field` over the whole sequence
at once (offline, iterated), as a ratio of the final misalignments.

    .venv/bin/python bench/field.py [--width 640 --height 480 --scenes 2 --drift-px 0.3 1 5]
    .venv/bin/python bench/field.py --sequence 6
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from typing import Any

import numpy as np

from elphel_host.calibrate.field import refine_extrinsics
from elphel_host.calibrate.field_running import RunningField
from elphel_host.tp.calibrated import CalibratedGeometry
from elphel_host.tp.images import QuadImages
from elphel_host.tp.processor import disparity_map
from elphel_sim.calib_rig import CalibRig, make_rig
from elphel_sim.calib_scene import (
    drifted_rig,
    misalignment_px,
    random_drift_px,
    rectified_rig,
    render_raw_quad,
)
from elphel_sim.quad import standard_scene, tile_truth


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


def scene_quads(moved: CalibRig, scenes: int) -> list[tuple[QuadImages, Any]]:
    """``scenes`` standard scenes through the drifted rig, with each one's tile truth."""
    full = float((1 << moved.sensor.bits) - 1)
    out = []
    for s in range(scenes):
        scene = standard_scene(rectified_rig(moved), seed=s)
        raw = render_raw_quad(scene, moved, seed=s + 1)
        out.append(
            (QuadImages((raw / full).astype(np.float32), bayer=moved.bayer), tile_truth(scene))
        )
    return out


def one_sequence(rig: CalibRig, max_px: float, quads: int, seed: int) -> dict[str, Any]:
    """`elphel tp --refine-extrinsics`'s refinement over a sequence; peer: calibrate field."""
    moved = drifted_rig(rig, random_drift_px(max_px, seed=seed))
    truth = geometry(moved)
    sequence = scene_quads(moved, quads)
    running = RunningField([(c.lens, c.R, c.t_mm) for c in rig.cameras])
    in_use, dsi_rms, seconds = [], [], 0.0
    for quad, tiles in sequence:
        in_use.append(float(misalignment_px(running.geometry, truth).max()))
        t0 = time.perf_counter()
        placed = running.place(quad)
        disparity = disparity_map(placed)["disparity"]
        running.update(placed, disparity)
        seconds += time.perf_counter() - t0
        scored = tiles.interior & tiles.textured
        dsi_rms.append(float(np.sqrt(np.mean((disparity - tiles.disparity)[scored] ** 2))))
    final = float(misalignment_px(running.geometry, truth).max())
    batch = refine_extrinsics(
        [q for q, _ in sequence], [(c.lens, c.R, c.t_mm) for c in rig.cameras]
    )
    peer = float(misalignment_px(CalibratedGeometry.from_cameras(batch.cameras), truth).max())
    reached = [i for i, m in enumerate([*in_use, final]) if m <= 0.02]
    return {
        "drift_px": max_px,
        "misalignment_in_use_px": [round(m, 4) for m in in_use],
        "misalignment_final_px": round(final, 4),
        "quads_to_0_02_px": reached[0] if reached else None,
        "dsi_rms_px": [round(e, 4) for e in dsi_rms],
        "calibrate_field_misalignment_px": round(peer, 4),
        "final_over_calibrate_field": round(final / peer, 3),
        "seconds_per_quad": round(seconds / quads, 2),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--scenes", type=int, default=2)
    p.add_argument("--drift-px", type=float, nargs="+", default=[0.3, 1.0, 5.0])
    p.add_argument("--seed", type=int, default=4, help="seed of the drifts")
    p.add_argument(
        "--sequence",
        type=int,
        metavar="N",
        help="instead: a sequence of N quads refined on the fly (elphel tp --refine-extrinsics)",
    )
    args = p.parse_args()
    rig = make_rig(args.width, args.height, seed=0)
    if args.sequence:
        cases = [one_sequence(rig, d, args.sequence, args.seed) for d in args.drift_px]
        peer = "elphel calibrate field over the whole sequence (offline, iterated)"
    else:
        cases = [one_drift(rig, d, args.scenes, args.seed) for d in args.drift_px]
        peer = "one update without re-measuring"
    result = {
        "benchmark": "field-sequence" if args.sequence else "field",
        "image": f"{args.width}x{args.height}",
        "scenes": args.sequence or args.scenes,
        "peer": peer,
        "cases": cases,
        "machine": platform.machine(),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
