"""``elphel calibrate solve VIEWS_DIR --pattern SPEC --out CALIB_DIR``: the calibration.

Detection is :mod:`elphel_host.calibrate.views`, the solve
:mod:`elphel_host.calibrate.solve`, the files :mod:`elphel_host.calibrate.result` and
the pictures :mod:`elphel_host.calibrate.pictures`; this module parses the options and
renders the result.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from elphel_host.calibrate.export import write_exports
from elphel_host.calibrate.pattern import Checkerboard
from elphel_host.calibrate.pictures import write_pictures
from elphel_host.calibrate.result import finite_json, write_calibration
from elphel_host.calibrate.solve import Calibration, calibrate
from elphel_host.calibrate.views import read_views
from elphel_host.cli_common import add_json_option, emit
from elphel_host.progress import ProgressLine


def register(subparsers: Any) -> None:
    """Add the ``calibrate`` subcommand with its ``solve`` action."""
    p = subparsers.add_parser(
        "calibrate",
        help="calibrate cameras and quads from views of a printed checkerboard",
        description="Camera and rig calibration from views of a checkerboard "
        "(docs/calibration.md).",
    )
    sub = p.add_subparsers(dest="calibrate_action", required=True, metavar="ACTION")
    s = sub.add_parser(
        "solve",
        help="detect the board in every view and solve intrinsics, rig, board poses and bend",
        description="Detect the checkerboard's corners in every view of VIEWS_DIR (image files "
        "of one camera, or one quad directory per view) and solve one bundle adjustment of "
        "every camera's intrinsics (OpenCV's rational model), the cameras' poses from camera 0, "
        "the board poses and the board's bend. Writes calibration.json, camN.yml (OpenCV "
        "FileStorage), residuals.png, coverage.png, uncertainty.png and exports/ (mrcal, "
        "COLMAP, Kalibr) into CALIB_DIR.",
    )
    s.add_argument("views", metavar="VIEWS_DIR", type=Path)
    s.add_argument(
        "--pattern",
        required=True,
        metavar="SPEC",
        help="checkerboard:COLSxROWS:SQUARE_MM, inner corners (a board of 10 x 7 squares is 9x6)",
    )
    s.add_argument("--out", required=True, type=Path, metavar="CALIB_DIR")
    s.add_argument(
        "--no-cross-validation",
        action="store_true",
        help="skip the two half-calibrations that measure how well the result repeats",
    )
    add_json_option(s)
    s.set_defaults(func=run_solve, parser=s)


def _human(cal: Calibration, path: Path) -> str:
    lines = [f"calibration: {path}", f"rms {cal.rms_px:.4f} px over {len(cal.cameras)} camera(s)"]
    for n, cam in enumerate(cal.cameras):
        lines.append(
            f"  cam{n}: rms {cam.rms_px:.4f} px, {cam.corners} corners, projection uncertainty "
            f"{cam.uncertainty_px:.4f} px, f {cam.lens.fx:.2f}/{cam.lens.fy:.2f} px, "
            f"t {', '.join(f'{v:.2f}' for v in cam.t_mm)} mm"
        )
    cv: dict[str, Any] = cal.cross_validation or {}
    for n, c in enumerate(cv.get("cameras", [])):
        lines.append(
            f"  cam{n} cross-validation: {c['rms_px']:.4f} px (expected {c['expected_px']:.4f})"
        )
    if "skipped" in cv:
        lines.append(f"  cross-validation skipped: {cv['skipped']}")
    lines.append(f"board bend {cal.warp_mm[0]:.3f}, {cal.warp_mm[1]:.3f} mm")
    if cal.missing:
        lines.append("board not found in: " + ", ".join(f"{v} (cam{c})" for v, c in cal.missing))
    if cal.outliers:
        lines.append(f"{len(cal.outliers)} outlier corner(s) left out (listed in calibration.json)")
    lines += [f"warning: {w}" for w in cal.warnings]
    return "\n".join(lines)


def run_solve(args: argparse.Namespace) -> int:
    """Detect, solve, write the calibration directory, print the summary."""
    try:
        pattern = Checkerboard.parse(args.pattern)
    except ValueError as e:
        args.parser.error(str(e))
    line = ProgressLine()
    obs = read_views(
        args.views,
        pattern,
        progress=lambda done, total: line.update(
            f"detecting: view {done} of {total}", done=done, total=total
        ),
    )
    line.update("solving")
    line.end()
    cal = calibrate(obs, cross_validate=not args.no_cross_validation)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    exports = write_exports(cal, args.out)
    path = write_calibration(cal, args.out, extra={"exports": exports})
    pictures = write_pictures(cal, args.out)
    result = {
        "rms_px": cal.rms_px,
        "calibration": str(path),
        "cameras": [
            {"rms_px": c.rms_px, "uncertainty_px": c.uncertainty_px, "corners": c.corners}
            for c in cal.cameras
        ],
        "cross_validation": cal.cross_validation,
        "outliers": len(cal.outliers),
        "missing": [{"view": v, "camera": c} for v, c in cal.missing],
        "warnings": list(cal.warnings),
        "pictures": [str(p) for p in pictures],
        "exports": exports,
    }
    emit(args, finite_json(result), _human(cal, path))
    return 0
