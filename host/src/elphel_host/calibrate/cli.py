"""``elphel calibrate capture|solve|psf|field``: a calibration from a checkerboard, and its upkeep.

The guided capture is :mod:`elphel_host.calibrate.capture`; detection is
:mod:`elphel_host.calibrate.views`, the solve :mod:`elphel_host.calibrate.solve`, the
files :mod:`elphel_host.calibrate.result` and the pictures
:mod:`elphel_host.calibrate.pictures`; this module parses the options and renders the
results.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from elphel_host import strict_json
from elphel_host.calibrate.capture import (
    COVERAGE_PNG,
    STATE_FILE,
    Attempt,
    CaptureSession,
    QuadCamera,
    SingleCamera,
    ViewSource,
    capture_views,
    open_session,
)
from elphel_host.calibrate.export import write_exports
from elphel_host.calibrate.field import (
    CORRECTIONS,
    FieldResult,
    pixels_per_unit,
    refine_extrinsics,
)
from elphel_host.calibrate.guide import CaptureLimits, text_map
from elphel_host.calibrate.pattern import Checkerboard
from elphel_host.calibrate.pictures import write_pictures
from elphel_host.calibrate.psf import check_psf_options, measure_psfs, write_psfs
from elphel_host.calibrate.result import (
    finite_json,
    read_cameras,
    write_calibration,
    write_updated_cameras,
)
from elphel_host.calibrate.solve import Calibration, calibrate
from elphel_host.calibrate.views import read_views
from elphel_host.camera.backends import connect
from elphel_host.cli_common import (
    add_camera_options,
    add_json_option,
    add_sensor_port_option,
    emit,
)
from elphel_host.errors import InputFormatError
from elphel_host.progress import ProgressLine
from elphel_host.tp.calibrated import calibration_file, read_calibration
from elphel_host.tp.images import QuadImages
from elphel_host.tp.io import read_quad_dir


def register(subparsers: Any) -> None:
    """Add the ``calibrate`` subcommand: capture, solve, psf and field, in a user's order."""
    p = subparsers.add_parser(
        "calibrate",
        help="calibrate cameras and quads from views of a printed checkerboard",
        description="Camera and rig calibration from views of a checkerboard "
        "(docs/calibration.md).",
    )
    sub = p.add_subparsers(dest="calibrate_action", required=True, metavar="ACTION")
    _register_capture(sub)
    _register_solve(sub)
    _register_psf(sub)
    _register_field(sub)


def _register_solve(sub: Any) -> None:
    s = sub.add_parser(
        "solve",
        help="detect the board in every view and solve intrinsics, rig, board poses and bend",
        description="Detect the checkerboard's corners in every view of VIEWS_DIR (image files "
        "of one camera, or one quad directory per view) and solve one bundle adjustment of "
        "every camera's intrinsics (OpenCV's rational model, plus a smooth residual grid where "
        "the corners show the lens needs one), the cameras' poses from camera 0, "
        "the board poses and the board's bend. Writes calibration.json, camN.yml (OpenCV "
        "FileStorage), residuals.png, coverage.png, uncertainty.png and exports/ (mrcal, "
        "COLMAP, Kalibr) into CALIB_DIR.",
    )
    s.add_argument("views", metavar="VIEWS_DIR", type=Path)
    _add_pattern_option(s)
    s.add_argument("--out", required=True, type=Path, metavar="CALIB_DIR")
    s.add_argument(
        "--no-cross-validation",
        action="store_true",
        help="skip the two half-calibrations that measure how well the result repeats",
    )
    s.add_argument(
        "--residual-grid",
        default="auto",
        type=_grid_option,
        metavar="auto|off|CXxCY",
        help="each lens's smooth residual on top of the rational model: auto (default) fits "
        "6x4 spline spans and keeps them when the corners support them, off never, CXxCY "
        "always with that many spans along x and y (2..32)",
    )
    add_json_option(s)
    s.set_defaults(func=run_solve, parser=s)


def _grid_option(text: str) -> str | tuple[int, int]:
    if text in ("auto", "off"):
        return text
    try:
        cx, cy = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}; allowed: auto, off or CXxCY spans such as 6x4"
        ) from None
    if not (2 <= cx <= 32 and 2 <= cy <= 32):
        raise argparse.ArgumentTypeError(f"{text!r}: spans 2..32 along each side")
    return cx, cy


def _add_pattern_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--pattern",
        required=True,
        metavar="SPEC",
        help="checkerboard:COLSxROWS:SQUARE_MM, inner corners (a board of 10 x 7 squares is 9x6)",
    )


def _register_capture(sub: Any) -> None:
    c = sub.add_parser(
        "capture",
        help="take views of a checkerboard from a camera (or a quad), guided, resumable",
        description="Take views of a checkerboard from a camera URL into VIEWS_DIR until it "
        "holds --views of them: each view is kept when a camera sees the whole board sharp, "
        "large enough and where none of its kept views had it, else the reason is shown. "
        "The coverage (text on stderr, VIEWS_DIR/capture/coverage.png) and hints on what "
        "is missing follow each view. Running again continues VIEWS_DIR.",
    )
    add_camera_options(c)
    _add_pattern_option(c)
    c.add_argument("--out", required=True, type=Path, metavar="VIEWS_DIR")
    c.add_argument(
        "--quad", action="store_true", help="a quad: all four ports on one trigger per view"
    )
    add_sensor_port_option(c, default=None, help="one camera: the sensor port (default 0)")
    c.add_argument("--views", type=int, default=20, metavar="N", help="views wanted (default 20)")
    c.add_argument(
        "--attempts", type=int, default=None, metavar="N", help="stop after N views taken"
    )
    c.add_argument(
        "--interval",
        type=float,
        default=1.0,
        metavar="S",
        help="seconds between views, to move the board (default 1)",
    )
    c.add_argument(
        "--max-blur-px",
        type=float,
        default=CaptureLimits.max_blur_px,
        metavar="PX",
        help=f"widest edges kept (default {CaptureLimits.max_blur_px:g} px)",
    )
    c.add_argument(
        "--min-area-percent",
        type=float,
        default=CaptureLimits.min_area_percent,
        metavar="P",
        help="smallest board kept, in %% of the image area "
        f"(default {CaptureLimits.min_area_percent:g})",
    )
    c.add_argument(
        "--timeout", type=float, default=60.0, metavar="S", help="seconds to wait for a frame"
    )
    add_json_option(c)
    c.set_defaults(func=run_capture, parser=c)


def _coverage_text(session: CaptureSession) -> list[str]:
    """The cameras' coverage grids, two side by side."""
    maps = [
        text_map(count, f"cam{cam}: views per cell") for cam, count in enumerate(session.counts())
    ]
    lines: list[str] = []
    for i in range(0, len(maps), 2):
        pair = maps[i : i + 2]
        lines += ["   ".join(row) for row in zip(*pair, strict=True)]
    return lines


def _attempt_text(attempt: Attempt, session: CaptureSession, wanted: int) -> list[str]:
    cams = [f"cam{c}: {s.reason}" for c, s in enumerate(attempt.seen)]
    if attempt.kept is None:
        return [f"view {attempt.number}: not kept: {attempt.reason}", *("  " + c for c in cams)]
    lines = [f"view {attempt.number}: kept as {attempt.kept} ({len(session.views)} of {wanted})"]
    lines += ["  " + c for c in cams] + _coverage_text(session)
    return lines + [f"  to do: {h}" for h in session.hints()]


def _capture_source(args: argparse.Namespace, camera: Any) -> ViewSource:
    if args.quad:
        return QuadCamera(camera, timeout_s=args.timeout)
    return SingleCamera(camera, port=args.sensor_port or 0)


def run_capture(args: argparse.Namespace) -> int:
    """Take views until VIEWS_DIR holds --views; print the summary."""
    try:
        pattern = Checkerboard.parse(args.pattern)
        limits = CaptureLimits(args.max_blur_px, args.min_area_percent)
    except ValueError as e:
        args.parser.error(str(e))
    if not args.camera:
        args.parser.error("capture needs a camera: give --camera URL or set ELPHEL_CAMERA_URL")
    if args.views < 1 or (args.attempts is not None and args.attempts < 1):
        args.parser.error("--views and --attempts: allowed at least 1")
    if args.quad and args.sensor_port is not None:
        args.parser.error("--sensor-port: one camera's port; --quad takes ports 0..3")
    session = open_session(args.out, pattern, cameras=4 if args.quad else 1)
    live: TextIO = sys.stderr
    print(f"{args.out}: {len(session.views)} view(s) so far, {args.views} wanted", file=live)
    done: list[Attempt] = []

    def report(attempt: Attempt, s: CaptureSession) -> None:
        done.append(attempt)
        print("\n".join(_attempt_text(attempt, s, args.views)), file=live, flush=True)

    with connect(args.camera, args.token, timeout_s=max(args.timeout, 30.0)) as camera:
        try:
            capture_views(
                _capture_source(args, camera),
                session,
                views=args.views,
                limits=limits,
                attempts=args.attempts,
                interval_s=args.interval,
                report=report,
            )
        except KeyboardInterrupt:
            raise KeyboardInterrupt(
                f"{len(session.views)} view(s) in {args.out}; the same command continues it"
            ) from None
    _capture_result(args, session, done)
    return 0


def _capture_result(args: argparse.Namespace, session: CaptureSession, done: list[Attempt]) -> None:
    todo = session.hints()
    state = session.state_dir
    result = {
        "views_dir": str(args.out),
        "views": len(session.views),
        "kept": sum(1 for a in done if a.kept),
        "attempts": len(done),
        "not_kept": [
            {"attempt": a.number, "reason": a.reason, "cameras": [s.reason for s in a.seen]}
            for a in done
            if a.kept is None
        ],
        "hints": todo,
        "coverage": str(state / COVERAGE_PNG),
        "state": str(state / STATE_FILE),
    }
    lines = [
        f"{args.out}: {len(session.views)} view(s) ({result['kept']} kept of "
        f"{len(done)} taken now); coverage map {state / COVERAGE_PNG}",
        *(f"to do: {h}" for h in todo),
        f"next: elphel calibrate solve {args.out} --pattern {session.pattern.spec} --out CALIB_DIR",
    ]
    emit(args, result, "\n".join(lines))


def _register_psf(sub: Any) -> None:
    p = sub.add_parser(
        "psf",
        help="measure each camera's blur over its field from the board's edges",
        description="Measure each camera's point-spread function (a Gaussian sigma per "
        "field cell) from the edges of the checkerboard in every view of VIEWS_DIR, and "
        "write the tile processor's aberration kernels (kernels.npy, the `kernels` entry "
        "of quad.json), one PSF grid per camera for `elphel mfsr --psf` (psf_camN_xS.npy) "
        "and psf.json into PSF_DIR.",
    )
    p.add_argument("views", metavar="VIEWS_DIR", type=Path)
    _add_pattern_option(p)
    p.add_argument("--out", required=True, type=Path, metavar="PSF_DIR")
    p.add_argument(
        "--cells", type=int, default=4, metavar="N", help="cells along the longer side (1..8)"
    )
    p.add_argument(
        "--scale", type=int, default=2, metavar="S", help="the MFSR scale of the PSF grids"
    )
    p.add_argument(
        "--target-sigma-px",
        type=float,
        default=1.3,
        metavar="PX",
        help="the Gaussian (sensor px) the kernels turn every cell's PSF into (default 1.3)",
    )
    add_json_option(p)
    p.set_defaults(func=run_psf, parser=p)


def run_psf(args: argparse.Namespace) -> int:
    """Measure the PSFs, write the files, print the per-cell sigmas."""
    try:
        pattern = Checkerboard.parse(args.pattern)
        check_psf_options(args.cells, args.scale, args.target_sigma_px)
    except ValueError as e:
        args.parser.error(str(e))
    fields, bayer = measure_psfs(args.views, pattern, cells=args.cells)
    doc = write_psfs(
        fields,
        args.out,
        bayer=bayer is not None,
        scale=args.scale,
        target_sigma_px=args.target_sigma_px,
    )
    lines = [f"PSFs of {len(fields)} camera(s) in {args.out} (cells {fields[0].step} px):"]
    for cam, field in enumerate(fields):
        lines.append(f"  cam{cam}: lens sigma per cell (px), {field.used} edges")
        lines += ["    " + " ".join(f"{s:5.2f}" for s in row) for row in field.sigma_px]
    lines.append(
        f'quad.json: "kernels": {strict_json.dumps(doc["kernels"], what="the kernels entry")}'
    )
    emit(args, {"psf_dir": str(args.out), **doc}, "\n".join(lines))
    return 0


def _grid_line(cal: Calibration) -> str:
    fit = cal.residual_grid
    if not fit.get("fitted", True):
        return "residual grid: off"
    spans = "x".join(str(v) for v in fit["cells"])  # type: ignore[attr-defined]
    if not fit["kept"]:
        return (
            f"residual grid: not kept ({spans} spans would explain {fit['chi2_drop']} of "
            f"the residuals' variance for {fit['parameters']} parameters): the rational "
            "model follows these lenses"
        )
    sizes = [c.lens.residual.size_px() for c in cal.cameras if c.lens.residual is not None]
    return (
        f"residual grid: {spans} spans kept, RMS "
        + ", ".join(f"{rms:.3f}" for rms, _ in sizes)
        + " px per camera (largest "
        + ", ".join(f"{top:.3f}" for _, top in sizes)
        + " px)"
    )


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
    lines.append(_grid_line(cal))
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
    cal = calibrate(
        obs, cross_validate=not args.no_cross_validation, residual_grid=args.residual_grid
    )
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
        "residual_grid_fit": cal.residual_grid,
        "outliers": len(cal.outliers),
        "missing": [{"view": v, "camera": c} for v, c in cal.missing],
        "warnings": list(cal.warnings),
        "pictures": [str(p) for p in pictures],
        "exports": exports,
    }
    emit(args, finite_json(result), _human(cal, path))
    return 0


def _register_field(sub: Any) -> None:
    f = sub.add_parser(
        "field",
        help="refine a quad's calibration for drift (lazy eye), from ordinary scenes",
        description="Estimate how cameras 1-3 of a calibrated quad have turned (tilt, "
        "azimuth, roll) and zoomed relative to camera 0 since CALIB_DIR was made, from the "
        "pair correlations of ordinary scenes (no pattern; part of each scene far away), "
        "and write the updated calibration.json and camN.yml into CALIB_DIR2.",
    )
    f.add_argument(
        "quads", metavar="QUAD_DIR", type=Path, nargs="+", help="quad directories of scenes"
    )
    f.add_argument(
        "--calibration",
        required=True,
        type=Path,
        metavar="CALIB_DIR",
        help="the calibration to refine (a directory or its calibration.json)",
    )
    f.add_argument(
        "--out", required=True, type=Path, metavar="CALIB_DIR2", help="where to write it"
    )
    f.add_argument(
        "--iterations", type=int, default=8, metavar="N", help="most updates (default 8)"
    )
    add_json_option(f)
    f.set_defaults(func=run_field, parser=f)


def _field_quads(paths: list[Path], image_size: tuple[int, int]) -> list[QuadImages]:
    quads = []
    for path in paths:
        quad = read_quad_dir(path).quad
        h, w = quad.images.shape[1:]
        if (w, h) != image_size:
            raise InputFormatError(
                f"{path}: images of {w}x{h}, the calibration is for {image_size[0]}x"
                f"{image_size[1]}; allowed: quads of the calibrated cameras at that size"
            )
        quads.append(quad)
    return quads


def _field_json(result: FieldResult) -> dict[str, Any]:
    cameras = []
    for n, corr in enumerate(result.corrections):
        scale = pixels_per_unit(result.cameras[n][0])
        cameras.append(
            {
                "mismatch_before_px": float(result.mismatch_before_px[n]),
                "mismatch_after_px": float(result.mismatch_after_px[n]),
                **{
                    f"{k}_mrad": float(v) * 1e3
                    for k, v in zip(CORRECTIONS[:3], corr[:3], strict=True)
                },
                "zoom_ppm": float(corr[3]) * 1e6,
                **{f"{k}_px": float(v) for k, v in zip(CORRECTIONS, corr * scale, strict=True)},
            }
        )
    return {
        "mismatch_before_px": float(np.sqrt(np.mean(result.mismatch_before_px**2))),
        "mismatch_after_px": float(np.sqrt(np.mean(result.mismatch_after_px**2))),
        "scatter_px": result.scatter_px,
        "iterations": result.iterations,
        "tiles": result.tiles,
        "infinity_tiles": result.infinity_tiles,
        "cameras": cameras,
    }


def run_field(args: argparse.Namespace) -> int:
    """Refine the calibration for drift, write CALIB_DIR2, print the mismatch."""
    if args.iterations < 1:
        args.parser.error(f"--iterations {args.iterations}; allowed: at least 1")
    source = calibration_file(args.calibration)
    geometry = read_calibration(source)  # checked: a readable calibration of a quad
    quads = _field_quads(list(args.quads), geometry.image_size)
    result = refine_extrinsics(quads, read_cameras(source), iterations=args.iterations)
    doc = _field_json(result)
    path = write_updated_cameras(
        source,
        list(result.cameras),
        args.out,
        extra={"field": finite_json({**doc, "quads": [str(q) for q in args.quads]})},
    )
    lines = [
        f"calibration: {path} ({result.iterations} update(s), {result.tiles} tiles, "
        f"{result.infinity_tiles} at infinity)",
        f"mismatch {doc['mismatch_before_px']:.4f} px before, "
        f"{doc['mismatch_after_px']:.4f} px after (pair scatter {result.scatter_px:.3f} px)",
    ]
    for n, cam in enumerate(doc["cameras"][1:], start=1):
        lines.append(
            f"  cam{n}: {cam['mismatch_before_px']:.4f} -> {cam['mismatch_after_px']:.4f} px; "
            f"tilt {cam['tilt_mrad']:+.4f}, azimuth {cam['azimuth_mrad']:+.4f}, roll "
            f"{cam['roll_mrad']:+.4f} mrad, zoom {cam['zoom_ppm']:+.0f} ppm"
        )
    emit(args, finite_json({"calibration": str(path), **doc}), "\n".join(lines))
    return 0
