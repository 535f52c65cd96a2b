"""`elphel stage ...`: status, move, home, zero, stop, calibrate, backlash, list.

The stage URL is any pyserial URL (``/dev/ttyUSB0``, ``socket://host:port``, a pty path),
from --stage or the environment variable
ELPHEL_STAGE_URL. Calibration results persist
in a small JSON file (--model) so later closed-loop moves can use them.
"""

from __future__ import annotations

import argparse
from dataclasses import asdict
from pathlib import Path
from typing import Any

from elphel_host.cli_common import (
    STAGE_URL_ENV,
    add_json_option,
    add_stage_model_option,
    add_stage_option,
    emit,
)
from elphel_host.errors import StageConnectionError
from elphel_host.progress import ProgressLine
from elphel_host.stage.client import StageClient
from elphel_host.stage.discovery import find_stage_boards
from elphel_host.stage.model import StageModel
from elphel_host.stage.positioning import Positioner


def _url(args: argparse.Namespace) -> str:
    url: str | None = args.stage
    if not url:
        raise StageConnectionError(f"no stage URL: pass --stage or set {STAGE_URL_ENV}")
    return url


def _status(args: argparse.Namespace) -> int:
    with StageClient(_url(args)) as client:
        st = client.status()
        caliper_mm = client.read_caliper_um() / 1000.0 if not st.moving else None
        ident = client.identify()
    result: dict[str, Any] = {
        "state": st.state,
        "steps": st.steps,
        "target_steps": st.target_steps,
        "homed": st.homed,
        "caliper_mm": caliper_mm,
        "alarm": st.alarm,
        "limit_switches": st.limits,
        "serial": ident.serial,
        "firmware": ident.firmware,
    }
    cal = "moving" if caliper_mm is None else f"{caliper_mm:.3f} mm"
    emit(args, result, f"{st.state} at step {st.steps} (homed: {st.homed}), caliper {cal}")
    return 0


class _ReportingClient:
    """The stage client as a move sees it, showing each caliper reading as progress.

    Progress is the distance covered towards the target (mm), from the readings the
    move takes anyway; nothing extra is asked of the stage.
    """

    def __init__(self, client: StageClient, line: ProgressLine) -> None:
        self._client = client
        self._line = line
        self.target_um: int | None = None
        self._start_um: int | None = None

    def __getattr__(self, name: str) -> Any:
        return getattr(self._client, name)

    def read_caliper_um(self) -> int:
        um = self._client.read_caliper_um()
        if self.target_um is not None:
            if self._start_um is None:
                # Where the move starts: nothing to show yet (and a move refused before
                # it starts leaves only its one-line error on stderr).
                self._start_um = um
                return um
            total_um = max(abs(self.target_um - self._start_um), 1)
            done_um = max(0, total_um - abs(self.target_um - um))
            self._line.update(
                f"stage: caliper {um / 1000:.3f} mm, target {self.target_um / 1000:.3f} mm",
                done=done_um / 1000,
                total=total_um / 1000,
                unit="mm",
            )
        return um


def _move(args: argparse.Namespace) -> int:
    model_path = Path(args.model)
    line = ProgressLine()
    with StageClient(_url(args)) as client:
        reporting = _ReportingClient(client, line)
        pos = Positioner(reporting, StageModel.load(model_path))  # type: ignore[arg-type]
        target = args.position_mm
        if args.relative:
            target += pos.read_mm()
        reporting.target_um = round(target * 1000)
        try:
            if args.open_loop:
                r = pos.move_open_loop(target)
            else:
                r = pos.move_closed_loop(target, tolerance_mm=args.tolerance_mm)
        finally:
            line.end()
    result = {
        "target_mm": r.target_mm,
        "caliper_mm": r.caliper_mm,
        "steps": r.steps,
        "estimate_mm": r.estimate_mm,
        "iterations": r.iterations,
        "closed_loop": not args.open_loop,
    }
    emit(
        args,
        result,
        f"at {r.caliper_mm:.3f} mm by caliper (step {r.steps}, target {r.target_mm} mm)",
    )
    return 0


def _home(args: argparse.Namespace) -> int:
    with StageClient(_url(args)) as client:
        st = client.home().wait(args.timeout)
        caliper_mm = client.read_caliper_um() / 1000.0
    emit(
        args,
        {"steps": st.steps, "homed": st.homed, "caliper_mm": caliper_mm},
        f"homed; caliper {caliper_mm:.3f} mm",
    )
    return 0


def _zero(args: argparse.Namespace) -> int:
    with StageClient(_url(args)) as client:
        if args.caliper:
            client.zero_caliper()
        else:
            client.zero()
    what = "caliper display" if args.caliper else "step position"
    emit(args, {"zeroed": "caliper" if args.caliper else "steps"}, f"{what} set to 0")
    return 0


def _stop(args: argparse.Namespace) -> int:
    with StageClient(_url(args)) as client:
        steps = client.stop()
    emit(args, {"steps": steps}, f"stopped at step {steps}")
    return 0


def _calibrate(args: argparse.Namespace) -> int:
    model_path = Path(args.model)
    with StageClient(_url(args)) as client:
        line = ProgressLine()
        pos = Positioner(client, StageModel(), log=line.say("calibrate: "))
        cal = pos.calibrate(
            span_mm=args.span_mm,
            start_mm=args.start_mm,
            repeats=args.repeats,
            progress=lambda done, total, text: line.update(
                f"calibrate: {text}", done=done, total=total
            ),
        )
        line.end()
    pos.model.save(model_path)
    result = {
        "mm_per_step": cal.mm_per_step,
        "spread_mm_per_step": cal.spread_mm_per_step,
        "runs": list(cal.runs),
        "offset_mm": cal.offset_mm,
        "span_mm": cal.span_mm,
        "model": str(model_path),
    }
    emit(
        args,
        result,
        f"{cal.mm_per_step:.7f} mm/step (spread {cal.spread_mm_per_step:.1e}, "
        f"{len(cal.runs)} runs over {cal.span_mm} mm); saved to {model_path}",
    )
    return 0


def _backlash(args: argparse.Namespace) -> int:
    model_path = Path(args.model)
    with StageClient(_url(args)) as client:
        pos = Positioner(client, StageModel.load(model_path))
        backlash_mm = pos.measure_backlash(at_mm=args.at_mm, repeats=args.repeats)
    pos.model.save(model_path)
    emit(
        args,
        {"backlash_mm": backlash_mm, "mm_per_step": pos.model.mm_per_step},
        f"backlash {backlash_mm:.4f} mm",
    )
    return 0


def _list(args: argparse.Namespace) -> int:
    boards = find_stage_boards()
    result = {"boards": [asdict(b) for b in boards]}
    lines = [
        f"{b.port or '(no tty)'}  {b.bridge} {b.vid:04x}:{b.pid:04x}  serial={b.serial_number}"
        for b in boards
    ]
    emit(args, result, "\n".join(lines) if lines else "no USB-UART stage bridges found")
    return 0


def register(subparsers: Any) -> None:
    """Add `stage` and its subcommands to the `elphel` parser."""
    p = subparsers.add_parser(
        "stage", help="linear stage: move, calibrate, closed-loop positioning"
    )
    sub = p.add_subparsers(dest="stage_cmd", required=True, metavar="COMMAND")

    def add(name: str, func: Any, help_text: str) -> argparse.ArgumentParser:
        sp = sub.add_parser(name, help=help_text, description=help_text)
        if name != "list":
            add_stage_option(sp)
        add_json_option(sp)
        sp.set_defaults(func=func)
        return sp

    add("status", _status, "state, step position and a fresh caliper reading")
    mv = add("move", _move, "move to POSITION_MM (caliper frame), closed loop unless --open-loop")
    mv.add_argument("position_mm", type=float, metavar="POSITION_MM")
    mv.add_argument("--relative", action="store_true", help="POSITION_MM is relative to here")
    mv.add_argument("--open-loop", action="store_true", help="trust the step model, no correction")
    mv.add_argument(
        "--tolerance-mm",
        type=float,
        default=0.005,
        help="extra tolerance beyond half a caliper LSB (default 0.005)",
    )
    add_stage_model_option(mv, help="calibration file")
    hm = add("home", _home, "home onto the min limit switch")
    hm.add_argument("--timeout", type=float, default=120.0, help="seconds (default 120)")
    zr = add("zero", _zero, "make the current position step 0 (or zero the caliper)")
    zr.add_argument("--caliper", action="store_true", help="pulse the caliper's zero line instead")
    add("stop", _stop, "stop the stage now")
    cb = add("calibrate", _calibrate, "measure mm/step with the caliper (homes first if needed)")
    cb.add_argument("--span-mm", type=float, default=80.0, help="move length (default 80)")
    cb.add_argument("--start-mm", type=float, default=10.0, help="start position (default 10)")
    cb.add_argument("--repeats", type=int, default=3, help="runs (default 3)")
    add_stage_model_option(cb, help="where to save the calibration")
    bl = add("backlash", _backlash, "measure backlash with the caliper")
    bl.add_argument("--at-mm", type=float, default=None, help="where (default: here)")
    bl.add_argument("--repeats", type=int, default=4, help="repeats (default 4)")
    add_stage_model_option(bl, help="calibration file")
    add("list", _list, "find stage boards (USB-UART bridges) and their serial ports")
