"""``elphel tp QUAD_DIR --out DSI.tif [--json]``: the tile processor on a quad directory.

``elphel tp capture --camera URL --out QUAD_DIR [--json]`` takes that directory from a quad
camera first (`elphel_host.tp.capture`). Both forms share one parser: ``capture`` in the
place of QUAD_DIR selects the capture (write ``./capture`` for a directory of that name).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from elphel_host.camera.backends import connect
from elphel_host.cli_common import add_camera_options, emit
from elphel_host.depth.cli import add_disagreement_option, max_disagreement
from elphel_host.depth.geometry import DepthOptics
from elphel_host.depth.products import DEFAULT_MIN_STRENGTH, dsi_depth, write_depth_products
from elphel_host.limits import HostLimits
from elphel_host.preview import NO_VALUE_RGB, Swatch, save_map_picture
from elphel_host.progress import ProgressLine
from elphel_host.tp.calibrated import CalibratedGeometry
from elphel_host.tp.capture import DEFAULT_TIMEOUT_S, TIMEOUT_PERIODS, capture_quad
from elphel_host.tp.config import TpConfig
from elphel_host.tp.dsi import write_ml_data
from elphel_host.tp.io import QuadSet, read_quad_dir
from elphel_host.tp.layout import read_layout
from elphel_host.tp.refining import run_refining
from elphel_host.tp.sequence import QuadJob, find_quads, plan_jobs, quad_dsi, run_sequence
from elphel_host.tp.texture import rendered_images, rgba_texture, write_texture
from elphel_host.tp.tile_pass import correlation_tiles
from elphel_host.tp.trigger import DEFAULT_TRIGGER_PERIOD_MS

CAPTURE = "capture"
USAGE = """elphel tp QUAD_DIR --out DSI.tif [--no-png] [--ply CLOUD.ply] [--json]
                         [tile processor options]
       elphel tp QUAD_DIR... --out-dir DIR [--scheduler ADDRESS] [--workers N] [--json]
       elphel tp QUAD_DIR... --out-dir DIR --refine-extrinsics [--refine-memory F] [--json]
       elphel tp capture --camera URL [--token T] --out QUAD_DIR [--geometry FILE]
                         [--calibration CALIB_DIR] [--trigger-period-ms MS] [--force]
                         [--json]"""


def register(subparsers: Any) -> None:
    """Add the ``tp`` subcommand (and its ``capture`` form)."""
    p = subparsers.add_parser(
        "tp",
        usage=USAGE,
        help="disparity space image (DSI) of a quad directory; `tp capture` takes one",
        description="Tile processor: per-tile sub-pixel disparity and strength of a quad image set "
        "(a quad directory in, a DSI TIFF out). `elphel tp capture` takes the quad set from a "
        "camera: one trigger, four sensor ports, the same timestamp.",
    )
    p.add_argument(
        "quad_dirs",
        nargs="+",
        metavar="QUAD_DIR",
        help="quad directory (quad.json + cam0..3.tif), or `capture` to take one from a camera; "
        "with --out-dir, any number of them or directories of them",
    )
    p.add_argument(
        "--out",
        metavar="PATH",
        help="DSI.tif to write (ImageJ stack); with `capture`, the quad directory to create",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    _add_capture_options(p)
    _add_tp_options(p)
    _add_sequence_options(p)
    p.set_defaults(func=run, parser=p)


def _add_capture_options(p: argparse.ArgumentParser) -> None:
    cap = p.add_argument_group("capture (elphel tp capture ...)")
    add_camera_options(cap)
    cap.add_argument(
        "--geometry",
        metavar="FILE",
        help='JSON {"cameras": [{"port": P, "position": [x, y]}, x4], "optics": {...}} '
        "(a quad.json works); default ports 0..3 on Elphel's square",
    )
    cap.add_argument(
        "--calibration",
        metavar="CALIB_DIR",
        help="the quad's calibration (`elphel calibrate solve`'s directory or its "
        "calibration.json): copied into the quad directory and named in quad.json, so "
        "`elphel tp` corrects the raw images for it",
    )
    cap.add_argument(
        "--trigger-period-ms",
        type=float,
        metavar="MS",
        help="common trigger period while capturing (default: the camera's repeating period, "
        f"else {DEFAULT_TRIGGER_PERIOD_MS:g} ms, longer if one frame's fetch, timed first, "
        "says the four frames would not be fetched in time)",
    )
    cap.add_argument(
        "--force", action="store_true", help="replace an existing non-empty quad directory"
    )
    cap.add_argument(
        "--timeout",
        type=float,
        metavar="S",
        help=f"seconds to wait for the frames (default {DEFAULT_TIMEOUT_S:g}, "
        f"or {TIMEOUT_PERIODS} trigger periods if longer)",
    )


def _add_tp_options(p: argparse.ArgumentParser) -> None:
    tp = p.add_argument_group("tile processor (elphel tp QUAD_DIR ...)")
    tp.add_argument(
        "--refine", type=int, default=1, metavar="N", help="refinement passes (default 1)"
    )
    tp.add_argument(
        "--scan",
        type=float,
        nargs="+",
        default=[0.0],
        metavar="D",
        help="first-pass target disparities; each tile keeps the strongest (default 0)",
    )
    tp.add_argument(
        "--fat-zero", type=float, default=TpConfig.fat_zero, help="fat zero (full scale = 1)"
    )
    tp.add_argument("--threads", type=int, default=TpConfig.threads, help="worker threads")
    tp.add_argument(
        "--no-png",
        action="store_true",
        help="do not write DSI.png beside DSI.tif (the disparity map with a colour bar in px, "
        "tiles weaker than --min-strength named as texture-less)",
    )
    tp.add_argument(
        "--ml-data", metavar="PATH", help="also write the correlation tiles in ML_DATA layout"
    )
    tp.add_argument(
        "--texture",
        metavar="PATH",
        help="also write an RGBA float32 TIFF: the four cameras blended at the measured disparity",
    )
    add_depth_options(tp)


def add_depth_options(group: Any) -> None:
    """``--ply``, ``--min-strength``, ``--max-disagreement``: depth map and point cloud."""
    group.add_argument(
        "--ply",
        metavar="CLOUD.ply",
        help="also write the point cloud (binary PLY, mm), CLOUD.png (a view of it), "
        "CLOUD_depth.tif (float32 depth in mm per tile) and CLOUD_depth.png; needs "
        "focal_length_mm, pixel_pitch_um and baseline_mm in quad.json optics, or a "
        "calibration in quad.json",
    )
    group.add_argument(
        "--min-strength",
        type=float,
        default=DEFAULT_MIN_STRENGTH,
        metavar="S",
        help=f"tiles weaker than S are left out of the cloud (default {DEFAULT_MIN_STRENGTH:g})",
    )
    add_disagreement_option(group)


def _add_sequence_options(p: Any) -> None:
    seq = p.add_argument_group("many quads (elphel tp QUAD_DIR... --out-dir DIR)")
    seq.add_argument(
        "--out-dir",
        metavar="DIR",
        help="one DSI per quad, DIR/<quad name>.tif; DSIs already there are kept, not redone",
    )
    seq.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="Dask scheduler of an existing cluster (tcp://host:8786); default: a local cluster",
    )
    seq.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="local cluster: worker processes (default: one per core)",
    )
    seq.add_argument(
        "--refine-extrinsics",
        action="store_true",
        help="calibrated quads: run them in order, each refining the calibration (lazy eye: "
        "cameras 1-3's tilt, azimuth, roll and zoom) for the next ones; the refined "
        "calibration is written to DIR/calibration.json",
    )
    seq.add_argument(
        "--refine-memory",
        type=float,
        default=0.5,
        metavar="F",
        help="with --refine-extrinsics: how much a quad's measurement counts one quad later, "
        "0..1 (default 0.5; 0: the latest quad alone)",
    )


# Options of one form that make no sense in the other (compared with their defaults).
_TP_ONLY = (
    "no_png",
    "refine",
    "scan",
    "fat_zero",
    "threads",
    "ml_data",
    "texture",
    "ply",
    "min_strength",
    "max_disagreement",
)
_CAPTURE_ONLY = ("geometry", "calibration", "trigger_period_ms", "force", "timeout")
_SEQUENCE_ONLY = ("scheduler", "workers", "refine_extrinsics", "refine_memory")


def _misplaced(args: argparse.Namespace, names: tuple[str, ...]) -> list[str]:
    parser: argparse.ArgumentParser = args.parser
    return ["--" + n.replace("_", "-") for n in names if getattr(args, n) != parser.get_default(n)]


def run(args: argparse.Namespace) -> int:
    """Dispatch ``elphel tp capture ...``, ``elphel tp QUAD_DIR ...`` and ``--out-dir``."""
    args.quad_dir = args.quad_dirs[0]
    if args.quad_dir == CAPTURE:
        if len(args.quad_dirs) > 1 or args.out_dir:
            args.parser.error("capture takes one quad set: `elphel tp capture ... --out QUAD_DIR`")
        wrong = _misplaced(args, _SEQUENCE_ONLY)
        if wrong:
            args.parser.error(f"{', '.join(wrong)}: only with --out-dir")
        return run_capture(args)
    wrong = _misplaced(args, _CAPTURE_ONLY)
    if wrong:
        args.parser.error(f"{', '.join(wrong)}: only with `elphel tp capture`")
    if args.out_dir:
        return run_many(args)
    wrong = _misplaced(args, _SEQUENCE_ONLY)
    if wrong:
        args.parser.error(f"{', '.join(wrong)}: only with --out-dir (many quads)")
    if len(args.quad_dirs) > 1:
        args.parser.error(
            f"{len(args.quad_dirs)} quad directories: give --out-dir DIR (one DSI each), "
            "or one QUAD_DIR with --out"
        )
    if not args.out:
        args.parser.error("--out DSI.tif is required (or --out-dir DIR for many quads)")
    return run_tp(args)


def run_capture(args: argparse.Namespace) -> int:
    """``elphel tp capture``: one trigger-synchronised quad set into a quad directory."""
    wrong = _misplaced(args, _TP_ONLY)
    if wrong:
        args.parser.error(f"{', '.join(wrong)}: only with `elphel tp QUAD_DIR`, not `capture`")
    if not args.out:
        args.parser.error("capture needs --out QUAD_DIR (the quad directory to create)")
    if not args.camera:
        hint = " (for a quad directory named capture, write ./capture)"
        args.parser.error(
            "capture needs a camera: give --camera URL or set ELPHEL_CAMERA_URL"
            + (hint if Path(CAPTURE, "quad.json").is_file() else "")
        )
    layout = read_layout(args.geometry) if args.geometry else None
    line = ProgressLine()

    def progress(done: int, total: int, message: str) -> None:
        line.update(f"tp capture: {done}/{total} {message}", done=done, total=total)

    t0 = time.perf_counter()
    # A frame may take long to come (a simulated board forms each full frame when it is
    # fetched, a busy host): without --timeout, as long as the request deadline allows.
    wait_s = args.timeout
    if wait_s is None:
        wait_s = max(DEFAULT_TIMEOUT_S, HostLimits.from_env().deadline_s)
    try:
        with connect(args.camera, args.token, timeout_s=max(wait_s, 30.0)) as camera:
            got = capture_quad(
                camera,
                args.out,
                layout=layout,
                trigger_period_ms=args.trigger_period_ms,
                force=args.force,
                timeout_s=args.timeout,
                progress=progress,
                calibration=args.calibration,
                say=line.say("tp capture: "),
            )
    finally:
        line.end()
    seconds = time.perf_counter() - t0
    cams = [cam.to_json() for cam in got.manifest.cameras]
    result: dict[str, Any] = {
        "quad_dir": str(got.path),
        "frames": {str(p): f for p, f in got.frames.items()},
        "timestamp_ns": got.timestamp_ns,
        "width": got.width,
        "height": got.height,
        "bayer": got.bayer,
        "cameras": [{k: c[k] for k in ("file", "port", "position", "frame")} for c in cams],
        "trigger": got.manifest.extra["capture"]["trigger"],
        "calibration": got.manifest.calibration,
        "seconds": round(seconds, 3),
    }
    frames = ", ".join(f"port {p} #{f}" for p, f in got.frames.items())
    human = (
        f"{got.path}: quad set of one trigger (t={got.timestamp_ns} ns; {frames}), "
        f"4 x {got.width}x{got.height} {got.bayer or 'mono'}, {seconds:.1f} s"
    )
    emit(args, result, human)
    return 0


def run_tp(args: argparse.Namespace) -> int:
    """``elphel tp QUAD_DIR --out DSI.tif``: the DSI of a quad directory."""
    qs = read_quad_dir(args.quad_dir)
    optics = None
    disagreement = None
    if not args.min_strength >= 0:
        args.parser.error(f"--min-strength {args.min_strength:g}; allowed: >= 0")
    if args.ply:
        disagreement = max_disagreement(args)
        optics = depth_optics(qs, source=str(Path(args.quad_dir, "quad.json")))
    config = TpConfig(
        refine_passes=args.refine,
        scan=tuple(args.scan),
        fat_zero=args.fat_zero,
        threads=args.threads,
    )
    dsi, result = quad_dsi(qs, args.out, config)
    if not args.no_png:
        result["png"] = str(
            save_disparity_png(
                Path(args.out).with_suffix(".png"), dsi, min_strength=args.min_strength
            )
        )
    if args.ml_data:
        corr = correlation_tiles(qs.quad, dsi["target_disparity"], config=config)
        write_ml_data(
            args.ml_data, corr, dsi["target_disparity"], extra={"fatZero": config.fat_zero}
        )
        result["ml_data"] = str(args.ml_data)
    if args.texture:
        rendered = rendered_images(qs.quad, dsi["disparity"])
        rgba = rgba_texture(rendered, bayer=qs.quad.bayer)
        write_texture(args.texture, rgba)
        result["texture"] = str(args.texture)
    if optics is not None:
        depth = dsi_depth(
            dsi,
            qs.quad,
            optics,
            min_strength=args.min_strength,
            max_disagreement=disagreement,
        )
        result["depth"] = {**depth.summary(), **write_depth_products(args.ply, depth, optics)}
    human = (
        f"{result['dsi']}: {result['tiles_x']}x{result['tiles_y']} tiles, {len(dsi)} layers, "
        f"{result['seconds']:.2f} s; median disparity {result['disparity_median']:.3f} px"
    )
    if "depth" in result:
        d = result["depth"]
        human += (
            f"\n{d['ply']}: {d['points']} points; left out {d['weak_tiles']} tiles below "
            f"strength {d['min_strength']:g}, {d['infinite_tiles']} at infinity and "
            f"{d['inconsistent_tiles']} with disagreeing directions"
        )
    emit(args, result, human)
    return 0


def depth_optics(qs: QuadSet, *, source: str) -> DepthOptics:
    """The optics that turn the quad's disparities into depth.

    A calibrated quad's come from its calibration (the virtual camera's focal length and
    the square's side; the pixel pitch from quad.json ``optics`` when it is there), any
    other quad's from quad.json ``optics``.
    """
    cal = qs.quad.geometry.calibration
    if isinstance(cal, CalibratedGeometry):
        pitch = (qs.manifest.optics or {}).get("pixel_pitch_um")
        return cal.depth_optics(None if pitch is None else float(pitch))
    return DepthOptics.from_optics(qs.manifest.optics, source=source)


def save_disparity_png(path: Path, dsi: dict[str, Any], *, min_strength: float) -> Path:
    """DSI.png: the disparity over its robust range, texture-less tiles named in the legend."""
    disparity = np.asarray(dsi["disparity"], dtype=np.float64)
    weak = ~(np.asarray(dsi["strength"]) >= min_strength)
    swatch = Swatch(
        f"no texture: strength < {min_strength:g} ({np.count_nonzero(weak)} tiles)",
        weak,
        NO_VALUE_RGB,
    )
    cell = max(1, int(np.ceil(400 / max(1, min(disparity.shape)))))
    return save_map_picture(
        disparity, path, unit="px", title="disparity (DSI)", swatches=[swatch], cell=cell
    )


def run_many(args: argparse.Namespace) -> int:
    """``elphel tp QUAD_DIR... --out-dir DIR``: one DSI per quad, on a Dask cluster."""
    if args.out:
        args.parser.error("--out and --out-dir: give one (--out-dir for many quads)")
    single_only = [
        f
        for f, v in (("--ml-data", args.ml_data), ("--texture", args.texture), ("--ply", args.ply))
        if v
    ]
    if single_only:
        args.parser.error(f"{', '.join(single_only)}: only with one QUAD_DIR and --out")
    if args.workers is not None and args.workers < 1:
        args.parser.error(f"--workers={args.workers}; allowed: >= 1")
    if args.workers is not None and args.scheduler:
        args.parser.error("--workers: only for the local cluster, not with --scheduler")
    quads = find_quads(args.quad_dirs)
    jobs = plan_jobs(quads, args.out_dir)
    Path(args.out_dir).mkdir(parents=True, exist_ok=True)
    if args.refine_extrinsics:
        return run_refine(args, jobs)
    if args.refine_memory != args.parser.get_default("refine_memory"):
        args.parser.error("--refine-memory: only with --refine-extrinsics")
    # one quad per single-threaded worker process, unless --threads says otherwise
    threads = args.threads if args.threads != args.parser.get_default("threads") else 1
    config = TpConfig(
        refine_passes=args.refine, scan=tuple(args.scan), fat_zero=args.fat_zero, threads=threads
    )
    progress = ProgressLine()
    failed_line = progress.say("failed: ")
    counts = {"done": 0, "skipped": 0, "failed": 0}

    def report(res: dict[str, Any], done: int, total: int) -> None:
        counts[res["status"]] += 1
        if res["status"] == "skipped":  # already there (reported first): not in the rate
            progress.restart(done)
        if res["status"] == "failed":
            failed_line(f"{res['quad']}: {res['error']}")
        progress.update(
            f"{done}/{total} quads ({counts['skipped']} skipped, {counts['failed']} failed)",
            done=done,
            total=total,
        )

    t0 = time.perf_counter()
    try:
        results = run_sequence(
            jobs, config, scheduler=args.scheduler, workers=args.workers, on_result=report
        )
    finally:
        progress.end()
    seconds = time.perf_counter() - t0
    result = {
        "out_dir": str(args.out_dir),
        "quads": results,
        "done": counts["done"],
        "skipped": counts["skipped"],
        "failed": counts["failed"],
        "seconds": round(seconds, 3),
        "scheduler": args.scheduler or "local",
    }
    human = (
        f"{args.out_dir}: {len(results)} quads, {counts['done']} done, {counts['skipped']} "
        f"skipped (already there), {counts['failed']} failed, {seconds:.1f} s"
    )
    emit(args, result, human)
    return 1 if counts["failed"] else 0


def run_refine(args: argparse.Namespace, jobs: list[QuadJob]) -> int:
    """``--out-dir DIR --refine-extrinsics``: the quads in order, refining the calibration."""
    if args.scheduler or args.workers is not None:
        args.parser.error(
            "--refine-extrinsics runs the quads in order here: no --scheduler, --workers"
        )
    if not 0 <= args.refine_memory < 1:
        args.parser.error(f"--refine-memory {args.refine_memory:g}; allowed: 0 <= F < 1")
    config = TpConfig(
        refine_passes=args.refine,
        scan=tuple(args.scan),
        fat_zero=args.fat_zero,
        threads=args.threads,
    )
    progress = ProgressLine()
    quad_line = progress.say("")
    counts = {"done": 0, "failed": 0}

    def report(res: dict[str, Any], done: int, total: int) -> None:
        counts[res["status"]] += 1
        if res["status"] == "failed":
            quad_line(f"{res['quad']}: failed: {res['error']}")
        else:
            r = res["refinement"]
            quad_line(
                f"{res['quad']}: mismatch {r['mismatch_before_px']:.4f} -> "
                f"{r['mismatch_after_px']:.4f} px"
                + ("" if r["updated"] else " (too little texture)")
            )
        progress.update(f"{done}/{total} quads ({counts['failed']} failed)", done=done, total=total)

    t0 = time.perf_counter()
    try:
        got = run_refining(jobs, args.out_dir, config, memory=args.refine_memory, on_result=report)
    finally:
        progress.end()
    seconds = time.perf_counter() - t0
    result = {
        "out_dir": str(args.out_dir),
        "quads": got.results,
        "done": counts["done"],
        "failed": counts["failed"],
        "calibration": str(got.calibration),
        "corrections": got.corrections,
        "seconds": round(seconds, 3),
    }
    human = (
        f"{args.out_dir}: {len(got.results)} quads, {counts['done']} done, {counts['failed']} "
        f"failed, {seconds:.1f} s; refined calibration {got.calibration}"
    )
    emit(args, result, human)
    return 1 if counts["failed"] else 0
