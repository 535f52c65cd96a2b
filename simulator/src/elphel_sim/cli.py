"""The `elphel-sim` command."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from elphel_sim import __version__
from elphel_sim.render.optics import MAX_LENS_BLUR_PX, LensBlur
from elphel_sim.scenarios import SCENARIOS


def tcp_port(text: str) -> int:
    """A TCP port for argparse: 0 (a free port) to 65535."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}; allowed: 0 (a free port) to 65535")
    return value


def lens_blur(text: str) -> LensBlur:
    """A lens blur for argparse: ``C`` or ``C:E`` (sigma in sensor px)."""
    try:
        return LensBlur.parse(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}; allowed: C or C:E, sigmas 0..{MAX_LENS_BLUR_PX:g} sensor pixels"
        ) from None


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="elphel-sim", description="Simulated Elphel rig.")
    p.add_argument("--version", action="version", version=f"elphel-sim {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    up = sub.add_parser("up", help="serve a simulated camera board (and stage) until stopped")
    up.add_argument("--scenario", default="default", choices=sorted(SCENARIOS))
    up.add_argument("--seed", type=int, default=0, help="seed of every noise source")
    up.add_argument(
        "--camera-port", type=tcp_port, default=0, help="camera REST port (0 = free port)"
    )
    up.add_argument("--stage-port", type=tcp_port, default=0, help="stage TCP port (0 = free port)")
    up.add_argument(
        "--firmware",
        choices=("camd", "elphel"),
        default="camd",
        help="camd: elphel-camd's REST API (default); elphel: a stock NC393's parsedit.php "
        "on the camera port and imgsrv on four consecutive free ports",
    )
    up.add_argument(
        "--public-reads",
        action="store_true",
        help="camd firmware: answer reads without the token, as elphel-camd --public-reads",
    )
    up.add_argument(
        "--lens-blur",
        type=lens_blur,
        default=None,
        metavar="C[:E]",
        help="the lenses blur the image: a Gaussian of sigma C sensor pixels on the optical "
        "axis, growing with the squared distance from it to E at the farthest corner "
        f"(0..{MAX_LENS_BLUR_PX:g}; default: a perfectly sharp lens)",
    )
    up.add_argument("--json", action="store_true", help="first stdout line: one JSON object")
    _add_calib_views(sub)
    _add_calib_scene(sub)
    return p


def _add_calib_views(sub: Any) -> None:
    cv = sub.add_parser(
        "calib-views",
        help="write a views directory of a simulated camera or quad looking at a checkerboard",
        description="Render views of a printed checkerboard through cameras with their own "
        "lens distortion, rotation, focal length and blur (Bayer, shot and read noise) and "
        "write them as `elphel calibrate solve` reads them, with truth.json beside them.",
    )
    cv.add_argument("out", metavar="VIEWS_DIR", type=Path)
    cv.add_argument("--cameras", type=int, choices=(1, 4), default=4)
    cv.add_argument("--views", type=int, default=24, help="board poses (default 24)")
    cv.add_argument("--width", type=int, default=1296)
    cv.add_argument("--height", type=int, default=968)
    cv.add_argument("--pattern", default="checkerboard:9x6:25", metavar="SPEC")
    cv.add_argument("--seed", type=int, default=0, help="seed of the rig, the poses and the noise")
    _add_residual_option(cv)
    cv.add_argument("--json", action="store_true", help="print one JSON object")


def _calib_views(args: argparse.Namespace) -> int:
    from elphel_host.calibrate.pattern import Checkerboard
    from elphel_sim.calib_rig import board_poses, make_rig, truth_json, write_views
    from elphel_sim.calib_target import PrintedBoard

    board = PrintedBoard(Checkerboard.parse(args.pattern))
    rig = make_rig(
        args.width, args.height, cameras=args.cameras, seed=args.seed, residual_px=args.residual_px
    )
    need = 1 if args.cameras == 1 else 2
    poses = board_poses(rig, board, args.views, seed=args.seed + 1, min_cameras=need)
    paths = write_views(args.out, rig, board, poses, seed=args.seed + 100)
    truth = args.out / "truth.json"
    truth.write_text(json.dumps(truth_json(rig, board, poses), indent=1) + "\n")
    result = {"views_dir": str(args.out), "views": len(paths), "truth": str(truth)}
    print(
        json.dumps(result) if args.json else f"{len(paths)} views in {args.out}, truth in {truth}"
    )
    return 0


def _non_negative_px(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}; allowed: a number of pixels >= 0") from None
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r}; allowed: a number of pixels >= 0")
    return value


def _add_residual_option(parser: Any) -> None:
    parser.add_argument(
        "--residual-px",
        type=_non_negative_px,
        default=0.0,
        metavar="PX",
        help="each lens's smooth non-radial error on top of its rational model, up to PX px "
        "per axis (default 0: the rational model is the whole lens)",
    )


def _add_calib_scene(sub: Any) -> None:
    cs = sub.add_parser(
        "calib-scene",
        help="write a quad directory of the quad's scene through the calibration rig's cameras",
        description="Render the quad's standard scene (planes at known disparities) through "
        "the cameras `calib-views` renders with the same --width, --height and --seed (their "
        "own distortion, rotation and focal length): the raw images a real quad records. "
        "truth.json beside the images holds the true disparity of every tile.",
    )
    cs.add_argument("out", metavar="QUAD_DIR", type=Path)
    cs.add_argument(
        "--calibration",
        metavar="CALIB_DIR",
        help="copy this calibration into QUAD_DIR and name it in quad.json",
    )
    cs.add_argument(
        "--rectified",
        metavar="DIR",
        type=Path,
        help="also write the same scene as ideal cameras in the common model record it",
    )
    cs.add_argument("--width", type=int, default=1296)
    cs.add_argument("--height", type=int, default=968)
    cs.add_argument("--seed", type=int, default=0, help="seed of the rig (as calib-views)")
    _add_residual_option(cs)
    cs.add_argument(
        "--scene-seed", type=int, default=None, metavar="N", help="seed of the scene (--seed)"
    )
    cs.add_argument(
        "--drift-px",
        type=float,
        default=None,
        metavar="PX",
        help="cameras 1-3 turned and zoomed by 0.3..PX px each (tilt, azimuth, roll, zoom) "
        "since the rig was calibrated, as a warm rig drifts",
    )
    cs.add_argument(
        "--drift-seed", type=int, default=0, metavar="N", help="seed of the drift (default 0)"
    )
    cs.add_argument("--json", action="store_true", help="print one JSON object")


def _calib_scene(args: argparse.Namespace) -> int:
    from elphel_sim.calib_rig import make_rig
    from elphel_sim.calib_scene import (
        drifted_rig,
        random_drift_px,
        rectified_rig,
        render_raw_quad,
        write_raw_quad_dir,
    )
    from elphel_sim.quad import render_quad, standard_scene, tile_truth, write_quad_dir

    rig = make_rig(args.width, args.height, cameras=4, seed=args.seed, residual_px=args.residual_px)
    drift = None
    if args.drift_px is not None:
        drift = random_drift_px(args.drift_px, seed=args.drift_seed)
        rig = drifted_rig(rig, drift)
    ideal = rectified_rig(rig)
    scene = standard_scene(ideal, seed=args.seed if args.scene_seed is None else args.scene_seed)
    truth = tile_truth(scene)
    doc = {
        "disparity": truth.disparity.tolist(),
        "interior": truth.interior.tolist(),
        "textured": truth.textured.tolist(),
        "label": truth.label.tolist(),
        "names": list(truth.names),
        "focal_length_px": ideal.intrinsics.focal_length_px,
        "baseline_mm": ideal.baseline_mm,
    }
    if drift is not None:
        doc["drift_px"] = drift.tolist()
    images = render_raw_quad(scene, rig, seed=args.seed + 7)
    write_raw_quad_dir(args.out, images, rig, calibration=args.calibration)
    (args.out / "truth.json").write_text(json.dumps(doc) + "\n")
    result: dict[str, Any] = {"quad_dir": str(args.out), "truth": str(args.out / "truth.json")}
    if args.rectified is not None:
        write_quad_dir(args.rectified, render_quad(scene, seed=args.seed + 7), ideal)
        (args.rectified / "truth.json").write_text(json.dumps(doc) + "\n")
        result["rectified"] = str(args.rectified)
    human = f"raw quad in {args.out}, truth in {result['truth']}"
    print(json.dumps(result) if args.json else human)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    commands = {"calib-views": _calib_views, "calib-scene": _calib_scene}
    if args.command in commands:
        try:
            return commands[args.command](args)
        except (OSError, ValueError) as e:
            print(f"elphel-sim: {e}", file=sys.stderr)
            return 1
    from elphel_sim.launcher import up

    try:
        return up(
            scenario=args.scenario,
            seed=args.seed,
            camera_port=args.camera_port,
            stage_port=args.stage_port,
            as_json=args.json,
            firmware=args.firmware,
            public_reads=args.public_reads,
            lens_blur=args.lens_blur,
        )
    except (OSError, ValueError) as e:
        print(f"elphel-sim: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
