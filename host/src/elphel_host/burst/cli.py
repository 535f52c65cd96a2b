"""``elphel burst plan|capture``: plan a sub-pixel burst and capture it.

The planning is :mod:`elphel_host.burst.plan`, the capture runner
:mod:`elphel_host.burst.capture` (quad bursts :mod:`elphel_host.burst.quad_capture`), the
files :mod:`elphel_host.burst.manifest` and :mod:`elphel_host.burst.io`; this module parses
the options, builds the rig from them and renders progress and results.
"""

from __future__ import annotations

import argparse
import os
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING, Any

from elphel_host.burst.capture import BurstRunner, CaptureResult, RigEngine, load_progress
from elphel_host.burst.plan import BurstPlan, plan_burst, read_plan, sensor_geometry, write_plan
from elphel_host.camera.backends import connect
from elphel_host.cli_common import (
    CAMERA_TOKEN_ENV,
    CAMERA_URL_ENV,
    add_json_option,
    add_sensor_port_option,
    add_stage_model_option,
    add_stage_option,
    emit,
    fail,
)
from elphel_host.errors import FusionError, InputFormatError, ScaleError
from elphel_host.mfsr.scale import MAX_SCALE, MIN_SCALE, check_scale
from elphel_host.progress import ProgressLine
from elphel_host.stage.client import StageClient
from elphel_host.stage.model import StageModel
from elphel_host.stage.positioning import Positioner

if TYPE_CHECKING:
    from elphel_host.mfsr.stream import FusionStream


def register(subparsers: Any) -> None:
    """Add the ``burst`` subcommand with its ``plan`` and ``capture`` actions."""
    p = subparsers.add_parser(
        "burst",
        help="plan (and capture) sub-pixel bursts",
        description="Sub-pixel bursts for multi-frame super-resolution.",
    )
    sub = p.add_subparsers(dest="burst_action", required=True, metavar="ACTION")
    _add_plan_parser(sub)
    _add_capture_parser(sub)


def _add_plan_parser(sub: Any) -> None:
    pl = sub.add_parser(
        "plan",
        help="stage positions giving the sub-pixel phases a scale needs",
        description="Positions along the stage axis for a x S burst, the "
        "recommended mount tilt (tan theta = 1/S; 1/(2S) with --bayer) and the parallax limit.",
    )
    pl.add_argument("--scale", type=int, required=True, metavar="S")
    pl.add_argument("--focal-length-mm", type=float, required=True, metavar="F")
    pl.add_argument(
        "--pixel-pitch-um",
        type=float,
        metavar="P",
        help="sensor pixel pitch (required unless --camera gives it)",
    )
    pl.add_argument(
        "--camera",
        metavar="URL",
        help="read the sensor's pixel pitch and mosaic (Bayer or mono) from this camera",
    )
    pl.add_argument(
        "--token",
        default=os.environ.get(CAMERA_TOKEN_ENV),
        help=f"the camera's token, if it asks for one (env {CAMERA_TOKEN_ENV})",
    )
    add_sensor_port_option(pl, help="the camera's sensor port read with --camera (default 0)")
    pl.add_argument(
        "--distance-mm",
        type=float,
        required=True,
        metavar="Z",
        help="distance of the object plane from the lens",
    )
    pl.add_argument("--mm-per-step", type=float, metavar="M", help="round to whole stage steps")
    pl.add_argument(
        "--frames", type=int, metavar="N", help="number of frames (default S*S, Bayer (2S)^2)"
    )
    pl.add_argument(
        "--bayer",
        action="store_true",
        help="plan for a Bayer sensor: the phases of each colour's 2 px period "
        "(tan theta = 1/(2S))",
    )
    pl.add_argument("--out", metavar="plan.json", help="save the plan as JSON")
    add_json_option(pl)
    pl.set_defaults(func=run_plan, parser=pl)


def _plan_sensor(args: argparse.Namespace) -> tuple[float, bool, dict[str, Any] | None]:
    """Pixel pitch and Bayer-ness: from the options, or read from --camera."""
    if args.camera is None:
        if args.pixel_pitch_um is None:
            args.parser.error("give --pixel-pitch-um, or --camera URL to read it from the sensor")
        return args.pixel_pitch_um, args.bayer, None
    with connect(args.camera, args.token) as camera:
        geometry = sensor_geometry(camera.info(), args.sensor_port)
    if args.pixel_pitch_um is not None and args.pixel_pitch_um != geometry.pixel_pitch_um:
        raise InputFormatError(
            f"--pixel-pitch-um {args.pixel_pitch_um} but the camera's {geometry.model} has "
            f"{geometry.pixel_pitch_um} um pixels; give one or the other"
        )
    if args.bayer and geometry.bayer is None:
        raise InputFormatError(f"--bayer but the camera's {geometry.model} is a mono sensor")
    sensor = {
        "model": geometry.model,
        "pixel_pitch_um": geometry.pixel_pitch_um,
        "bayer": geometry.bayer,
        "port": args.sensor_port,
    }
    return geometry.pixel_pitch_um, geometry.bayer is not None, sensor


def run_plan(args: argparse.Namespace) -> int:
    pitch, bayer, sensor = _plan_sensor(args)
    plan = plan_burst(
        scale=args.scale,
        focal_length_mm=args.focal_length_mm,
        pixel_pitch_um=pitch,
        distance_mm=args.distance_mm,
        mm_per_step=args.mm_per_step,
        frames=args.frames,
        bayer=bayer,
    )
    result = plan.to_json()
    if sensor is not None:
        result["sensor"] = sensor
    if args.out:
        write_plan(args.out, plan)
        result["out"] = str(args.out)
    lines = [
        f"x{plan.scale} {'Bayer ' if plan.bayer else ''}burst, {plan.frames} frames, "
        f"{plan.px_per_mm:.2f} px/mm at the "
        f"object plane, travel {plan.travel_mm:.4f} mm"
    ]
    for i, (p, sh) in enumerate(zip(plan.positions_mm, plan.shifts_px, strict=True)):
        st = f"  step {plan.steps[i]}" if plan.steps is not None else ""
        lines.append(f"  {i:3d}: {p:.5f} mm{st}  shift dy={sh[0]:.3f} dx={sh[1]:.3f} px")
    lines += [f"note: {n}" for n in plan.notes]
    if args.out:
        lines.append(f"saved {args.out}")
    emit(args, result, "\n".join(lines))
    return 0


# -- capture -------------------------------------------------------------------------------


def _add_capture_parser(sub: Any) -> None:
    cp = sub.add_parser(
        "capture",
        help="move, settle, capture and record every frame of a plan (resumable)",
        description="Capture a planned burst into a burst directory. Each frame "
        "is saved as it arrives; running the same command again completes a partial burst. "
        "With --fuse the frames are also registered for fusion while the stage moves, and "
        "the fused image (what 'elphel mfsr OUT --scale S --method M --out FUSED' gives) is "
        "written moments after the last frame; a fusion failure keeps the frames and exits 1. "
        "With several --camera, every camera takes its frame at each position together and "
        "each gets its burst directory OUT/cam0, OUT/cam1, ... in the order given.",
    )
    cp.add_argument(
        "--camera",
        action="append",
        metavar="URL",
        help="camera URL: http://HOST:PORT (elphel-camd) or nc393://HOST[:PORT][?imgsrv=BASE] "
        f"(a stock NC393); repeat for several cameras (env {CAMERA_URL_ENV}: one camera)",
    )
    cp.add_argument(
        "--token",
        action="append",
        help="elphel-camd's bearer token: one for every camera, or one per --camera in "
        f"their order (env {CAMERA_TOKEN_ENV})",
    )
    add_stage_option(cp)
    cp.add_argument("--plan", type=Path, required=True, help="plan JSON (elphel burst plan --out)")
    cp.add_argument("--out", type=Path, required=True, help="burst directory to write")
    add_sensor_port_option(cp, help="sensor port of the camera (default 0)")
    cp.add_argument("--start-mm", type=float, help="plan origin on the stage (default: here)")
    add_stage_model_option(cp)
    cp.add_argument("--settle-s", type=float, default=0.05, help="wait after each move")
    cp.add_argument("--focal-length-mm", type=float, help="record optics in the manifest")
    cp.add_argument("--pixel-pitch-um", type=float)
    cp.add_argument("--distance-mm", type=float)
    cp.add_argument(
        "--quad",
        action="store_true",
        help="capture a quad burst: at each position one trigger-synchronised set of the "
        "four sensor ports (OUT/quad.json + OUT/cam0..cam3 burst directories)",
    )
    cp.add_argument(
        "--geometry",
        type=Path,
        metavar="FILE",
        help="with --quad: ports, positions and optics of the quad (as for elphel tp capture)",
    )
    add_json_option(cp)
    fz = cp.add_argument_group("fusion while capturing (elphel mfsr on the finished burst)")
    fz.add_argument(
        "--fuse",
        action="store_true",
        help="register each frame as it arrives and write the fused image at the end",
    )
    fz.add_argument(
        "--scale",
        type=int,
        metavar="S",
        help=f"up-sampling factor {MIN_SCALE}..{MAX_SCALE} (default: the plan's)",
    )
    fz.add_argument(
        "--method",
        choices=("robust", "baseline"),
        help="as elphel mfsr --method (default robust)",
    )
    fz.add_argument(
        "--fused-out",
        type=Path,
        metavar="FUSED.tif",
        help="fused TIFF, 16-bit DN, with a PNG preview next to it (default OUT/fused.tif)",
    )
    cp.set_defaults(func=run_capture, parser=cp)


def _fuse_options(args: argparse.Namespace, plan: BurstPlan) -> tuple[int, str, Path] | None:
    """(scale, method, fused TIFF) for --fuse, or None; wrong combinations are usage errors."""
    parser: argparse.ArgumentParser = args.parser
    if not args.fuse:
        extra = [
            option
            for option, value in (
                ("--scale", args.scale),
                ("--method", args.method),
                ("--fused-out", args.fused_out),
            )
            if value is not None
        ]
        if extra:
            parser.error(f"{', '.join(extra)}: allowed only with --fuse")
        return None
    scale = args.scale if args.scale is not None else plan.scale
    try:
        scale = check_scale(scale)
    except ScaleError as e:
        source = "--scale" if args.scale is not None else f"the plan {args.plan}"
        parser.error(f"--fuse: scale={e.value!r} from {source}; allowed: {e.allowed}")
    out = args.fused_out if args.fused_out is not None else args.out / "fused.tif"
    return scale, args.method or "robust", out


def _manifest_top(args: argparse.Namespace, plan: BurstPlan) -> dict[str, Any]:
    """The manifest's top-level fields known before the stage is read."""
    recorded = {"scale": plan.scale, "tilt_deg": plan.tilt_deg}
    top: dict[str, Any] = {"plan": {k: v for k, v in recorded.items() if v is not None}}
    optics = {
        "focal_length_mm": args.focal_length_mm,
        "pixel_pitch_um": args.pixel_pitch_um,
        "object_distance_mm": args.distance_mm,
    }
    if all(v is not None for v in optics.values()):
        top["optics"] = optics
    return top


def _cameras_and_tokens(args: argparse.Namespace) -> tuple[list[str], list[str | None]]:
    """The --camera URLs (else the environment's) and a token for each."""
    cameras = args.camera or [u for u in [os.environ.get(CAMERA_URL_ENV)] if u]
    tokens: list[str | None] = args.token or [os.environ.get(CAMERA_TOKEN_ENV)]
    if not cameras or not args.stage:
        args.parser.error("give --camera and --stage (or ELPHEL_CAMERA_URL / ELPHEL_STAGE_URL)")
    if len(tokens) == 1:
        tokens = tokens * len(cameras)
    if len(tokens) != len(cameras):
        args.parser.error(
            f"{len(tokens)} --token for {len(cameras)} --camera: give one token for all "
            "cameras or one per camera"
        )
    return cameras, tokens


def run_capture(args: argparse.Namespace) -> int:
    cameras, tokens = _cameras_and_tokens(args)
    if args.geometry is not None and not args.quad:
        args.parser.error("--geometry: allowed only with --quad")
    plan = read_plan(args.plan)
    if len(cameras) > 1:
        return run_multi_capture(args, plan, cameras, tokens)
    args.camera, args.token = cameras[0], tokens[0]
    if args.quad:
        return run_quad_capture(args, plan)
    fuse = _fuse_options(args, plan)
    if fuse is not None:  # an output that cannot be written fails before the rig moves
        fuse[2].parent.mkdir(parents=True, exist_ok=True)
    top = _manifest_top(args, plan)
    line = ProgressLine()
    with ExitStack() as stack:
        stream = None
        if fuse is not None:
            # imported here: plain captures do not load OpenCV and SciPy
            from elphel_host.mfsr.stream import FusionStream

            stream = stack.enter_context(
                FusionStream(frames=len(plan.positions_mm), scale=fuse[0], method=fuse[1])
            )
        with StageClient(args.stage) as stage, connect(args.camera, args.token) as camera:
            positioner = Positioner(stage, StageModel.load(args.model))
            so_far = load_progress(args.out)
            start_mm = _start_and_stage(args, positioner, plan, top, so_far)
            line.restart(len(so_far.frames) if so_far is not None else 0)  # resumed: count anew
            engine = RigEngine(positioner, camera, port=args.sensor_port, settle_s=args.settle_s)

            def progress(done: int, total: int, message: str) -> None:
                fusion = "" if stream is None else f"; fusion: {stream.status()}"
                line.update(f"burst: {done}/{total} {message}{fusion}", done=done, total=total)

            runner = BurstRunner(
                engine,
                plan.positions_mm,
                args.out,
                start_mm=start_mm,
                top=top,
                progress=progress,
                on_frame=None if stream is None else stream.frame_stored,
            )
            try:
                result = runner.start().wait()
            except KeyboardInterrupt:
                raise interrupted(args.out, len(plan.positions_mm), "frames") from None
            line.end()
        summary = _capture_summary(result, len(plan.positions_mm), start_mm)
        human = [
            f"{result.directory}: {len(result.captured)} frames captured, "
            f"{len(result.skipped)} already there, in {result.seconds:.1f} s"
        ]
        error = None
        if stream is not None and fuse is not None:
            fused, said = _finish_fusion(stream, fuse, result.directory, line)
            error = fused.get("error")
            human.append(said)
            summary["fusion"] = fused
    emit(args, summary, "\n".join(human))
    return 0 if error is None else fail(error)


def _finish_fusion(
    stream: FusionStream, fuse: tuple[int, str, Path], burst: Path, line: ProgressLine
) -> tuple[dict[str, Any], str]:
    """Finish the fusion and write the image: its summary (or the error) and a line for people."""
    from elphel_host.mfsr.stream import finish_and_write

    scale, _method, out = fuse
    try:
        fused = finish_and_write(stream, out, burst=burst, progress=line.say("fusion: "))
    except FusionError as e:
        return {"error": str(e)}, str(e)
    excluded = "; ".join(f"{e['index']}: {e['reason']}" for e in fused["excluded"])
    said = (
        f"{fused['out']}: {fused['method']} x{scale}, {fused['used']}/"
        f"{fused['frames']} frames, written {fused['after_capture_s']:.2f} s "
        "after the last frame" + (f"; excluded {excluded}" if excluded else "")
    )
    return fused, said


def _capture_summary(result: CaptureResult, frames: int, start_mm: float) -> dict[str, Any]:
    return {
        "out": str(result.directory),
        "captured": result.captured,
        "already_present": result.skipped,
        "frames": frames,
        "start_mm": start_mm,
        "seconds": round(result.seconds, 2),
    }


def run_quad_capture(args: argparse.Namespace, plan: BurstPlan) -> int:
    """``elphel burst capture --quad``: a quad-burst directory, resumable."""
    from elphel_host.burst.quad_capture import QuadRigEngine, capture_quad_burst
    from elphel_host.tp.layout import read_layout

    if args.fuse:
        args.parser.error("--fuse: not with --quad (run elphel depth on the quad burst)")
    layout = read_layout(args.geometry) if args.geometry else None
    top = _manifest_top(args, plan)
    line = ProgressLine()
    with StageClient(args.stage) as stage, connect(args.camera, args.token) as camera:
        positioner = Positioner(stage, StageModel.load(args.model))
        so_far = load_progress(args.out / "cam0")
        start_mm = _start_and_stage(args, positioner, plan, top, so_far)
        line.restart(len(so_far.frames) if so_far is not None else 0)  # resumed: count anew
        engine = QuadRigEngine(positioner, camera, layout=layout, settle_s=args.settle_s)

        def progress(done: int, total: int, message: str) -> None:
            line.update(f"quad burst: {done}/{total} {message}", done=done, total=total)

        try:
            result = capture_quad_burst(
                engine, plan.positions_mm, args.out, start_mm=start_mm, top=top, progress=progress
            )
        except KeyboardInterrupt:
            raise interrupted(args.out / "cam0", len(plan.positions_mm), "quad sets") from None
        line.end()
    summary = _capture_summary(result, len(plan.positions_mm), start_mm)
    summary["quad"] = True
    human = (
        f"{result.directory}: {len(result.captured)} quad sets captured, "
        f"{len(result.skipped)} already there, in {result.seconds:.1f} s"
    )
    emit(args, summary, human)
    return 0


def interrupted(out: Path, total: int, what: str) -> KeyboardInterrupt:
    """Ctrl-C during a capture: how much of it is kept in ``out``, and how to resume."""
    try:
        so_far = load_progress(out)
    except InputFormatError:
        so_far = None
    kept = len(so_far.frames) if so_far is not None else 0
    return KeyboardInterrupt(
        f"{kept} of {total} {what} kept in {out}; the same command captures the rest"
    )


def run_multi_capture(
    args: argparse.Namespace, plan: BurstPlan, cameras: list[str], tokens: list[str | None]
) -> int:
    """``elphel burst capture --camera A --camera B ...``: a burst per camera, resumable."""
    from elphel_host.burst.multi_capture import MultiCameraEngine, capture_multi_burst

    if args.quad:
        args.parser.error("--quad: a quad camera is one --camera, not several")
    if args.fuse:
        args.parser.error("--fuse: with one --camera only; fuse each OUT/camN with elphel mfsr")
    top = _manifest_top(args, plan)
    line = ProgressLine()
    with ExitStack() as stack:
        stage = stack.enter_context(StageClient(args.stage))
        clients = [stack.enter_context(connect(u, t)) for u, t in zip(cameras, tokens, strict=True)]
        positioner = Positioner(stage, StageModel.load(args.model))
        start_mm = _start_and_stage(args, positioner, plan, top, load_progress(args.out / "cam0"))
        engine = MultiCameraEngine(
            positioner, clients, port=args.sensor_port, settle_s=args.settle_s
        )

        def progress(done: int, total: int, message: str) -> None:
            line.update(f"burst: {done}/{total} {message}", done=done, total=total)

        result = capture_multi_burst(
            engine, plan.positions_mm, args.out, start_mm=start_mm, top=top, progress=progress
        )
        line.end()
    summary = _capture_summary(result, len(plan.positions_mm), start_mm)
    summary["cameras"] = [str(args.out / f"cam{i}") for i in range(len(cameras))]
    human = (
        f"{result.directory}: {len(cameras)} cameras, {len(result.captured)} positions "
        f"captured, {len(result.skipped)} already there, in {result.seconds:.1f} s"
    )
    emit(args, summary, human)
    return 0


def _start_and_stage(
    args: argparse.Namespace,
    positioner: Positioner,
    plan: BurstPlan,
    top: dict[str, Any],
    so_far: Any,
) -> float:
    """Where the plan starts; also sets the stage's entry of the manifest in ``top``.

    The start is kept from an interrupted run, else ``--start-mm``, else where the
    carriage is now.
    """
    if so_far is not None:
        start_mm = float(so_far.extra["capture"]["start_mm"])
    elif args.start_mm is not None:
        start_mm = args.start_mm
    else:
        start_mm = round(positioner.read_mm(), 2)
    top["stage"] = {"mm_per_step": positioner.model.mm_per_step}
    if plan.tilt_deg is not None:
        top["stage"]["axis_angle_deg"] = plan.tilt_deg
    return start_mm
