"""`elphel camera ...`: talk to a camera daemon (info, get, set, capture, watch)."""

from __future__ import annotations

import argparse
import contextlib
import functools
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from elphel_host import strict_json
from elphel_host.camera.backends import connect
from elphel_host.camera.client import (
    CameraClient,
    CameraHTTPError,
    CameraUnauthorizedError,
    PartialBurstError,
)
from elphel_host.camera.events import CameraEvent
from elphel_host.camera.protocol import CameraInterface
from elphel_host.camera.unsupported import NoEventsNoRegisters
from elphel_host.cli_common import (
    add_camera_options,
    add_json_option,
    add_sensor_port_option,
    emit,
)
from elphel_host.errors import (
    CameraAuthError,
    CameraClientError,
    CameraParameterError,
    UnsupportedError,
)
from elphel_host.fileio import replacing, write_atomic
from elphel_host.shown import shown


def register(sub: Any) -> None:
    common = argparse.ArgumentParser(add_help=False)
    add_camera_options(common)
    add_json_option(common)
    ported = argparse.ArgumentParser(add_help=False)
    add_sensor_port_option(ported)

    p = sub.add_parser("camera", help="camera daemon: info, params, get, set, capture, watch")
    cmd = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    info = cmd.add_parser(
        "info", parents=[common], help="board, daemon version, ports and their sensors"
    )
    info.set_defaults(func=cmd_info, parser=info)

    params = cmd.add_parser(
        "params",
        parents=[common, ported],
        help="every frame parameter: current value, unit, the range that applies now, meaning",
    )
    params.set_defaults(func=cmd_params, parser=params)

    get = cmd.add_parser("get", parents=[common, ported], help="print frame parameters")
    get.add_argument("names", nargs="*", metavar="NAME", help="parameters (default: all)")
    get.add_argument("--frame", type=int, help="parameters of a recent or scheduled frame")
    get.set_defaults(func=cmd_get, parser=get)

    _add_set(cmd, [common, ported])
    _add_capture(cmd, [common, ported])

    watch = cmd.add_parser(
        "watch",
        parents=[common],
        help="print the daemon's events (frames, parameter changes, errors)",
    )
    watch.add_argument(
        "--types", default="frame,params,error", help="comma-separated: frame,params,error"
    )
    add_sensor_port_option(watch, default=None, help="only this sensor port's events")
    watch.add_argument("--count", type=int, help="stop after N events")
    watch.set_defaults(func=cmd_watch, parser=watch)


def _add_set(cmd: Any, parents: list[argparse.ArgumentParser]) -> None:
    set_ = cmd.add_parser(
        "set",
        parents=parents,
        help="set parameters (e.g. EXPOS=5000 GAINR=0x20000; names in any case, "
        "`elphel camera params` lists them): all or none on elphel-camd; "
        "on a stock NC393 checked first, written in one request, read back",
    )
    set_.add_argument("assignments", nargs="+", metavar="NAME=VALUE")
    when = set_.add_mutually_exclusive_group()
    when.add_argument("--frame", type=int, help="apply at this absolute frame")
    when.add_argument("--ahead", type=int, help="apply this many frames from now")
    set_.set_defaults(func=cmd_set, parser=set_)


def _add_capture(cmd: Any, parents: list[argparse.ArgumentParser]) -> None:
    cap = cmd.add_parser(
        "capture",
        parents=parents,
        help="capture the next frame (or a recent one, or a burst) as a 16-bit TIFF",
    )
    cap.add_argument("--out", type=Path, help="TIFF path (default: portP-frameN.tif)")
    cap.add_argument("--png", type=Path, help="also write an 8-bit PNG preview here")
    cap.add_argument("--frame", type=int, help="fetch this frame from the ring buffer")
    cap.add_argument(
        "--count", type=int, default=1, help="N consecutive frames as one multi-page TIFF"
    )
    cap.add_argument(
        "--keep-partial",
        action="store_true",
        help="a burst that breaks off: write the frames received (the command still fails)",
    )
    cap.add_argument(
        "--join",
        action="store_true",
        help="photo-finish: join the N composites into one image (rows in time order) "
        "and record each row's time",
    )
    cap.set_defaults(func=cmd_capture, parser=cap)


def _client(args: argparse.Namespace, *, retry_s: float = 0.0) -> CameraInterface:
    """The camera of the command line; one-shot commands fail at once when it is down."""
    if not args.camera:
        args.parser.error("no camera URL: give --camera (or --url) or set ELPHEL_CAMERA_URL")
    client = connect(args.camera, args.token)
    if isinstance(client, CameraClient):
        client.retry_s = retry_s
    return client


def _said_plainly(func: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """Turn the daemon's refusals into what the user needs to hear.

    A 401 with a token given means the token is wrong (the daemon says only that the
    request needs one); a refused value says *why* (must be even, out of range, ...).
    """

    @functools.wraps(func)
    def run(args: argparse.Namespace) -> int:
        try:
            return func(args)
        except CameraUnauthorizedError as e:
            if getattr(args, "token", None):
                raise CameraAuthError(
                    f"wrong token: the camera at {args.camera} refused it (HTTP {e.status}); "
                    "check --token or ELPHEL_CAMERA_TOKEN (elphel-sim up prints it)"
                ) from e
            raise CameraAuthError(
                f"the camera at {args.camera} needs its token (HTTP {e.status}): give --token "
                "or set ELPHEL_CAMERA_TOKEN"
            ) from e
        except CameraHTTPError as e:
            if e.status in (409, 422) and e.parameter and e.allowed is not None:
                raise CameraParameterError(
                    f"{refusal(e.parameter, e.value, e.allowed)}; HTTP {e.status}",
                    parameter=e.parameter,
                    value=e.value,
                    allowed=e.allowed,
                ) from e
            raise

    return run


_RANGE = re.compile(r"^(-?\d+)\.\.(-?\d+)")


def refusal(name: str, value: Any, allowed: str) -> str:
    """``WOI_WIDTH=641 refused: must be even (allowed: 2..2592 (even))``."""
    reason = "not allowed"
    found = _RANGE.match(allowed)
    if isinstance(value, int) and not isinstance(value, bool):
        if found and not int(found.group(1)) <= value <= int(found.group(2)):
            reason = f"out of range {found.group(1)}..{found.group(2)}"
        elif "even" in allowed and value % 2:
            reason = "must be even"
        elif "multiple of" in allowed:
            reason = "must be " + allowed[allowed.index("a multiple of") :]
    elif not isinstance(value, int):
        reason = "not an integer"
    return f"{name}={value!r} refused: {reason} (allowed: {allowed})"


def _parse_assignments(parser: argparse.ArgumentParser, items: list[str]) -> dict[str, int]:
    out: dict[str, int] = {}
    for item in items:
        name, sep, text = item.partition("=")
        try:
            if not sep or not name:
                raise ValueError
            # Elphel's names are upper case; `expos=5000` means EXPOS.
            out[name.strip().upper()] = int(text.strip(), 0)
        except ValueError:
            parser.error(f"{item!r}: give NAME=VALUE with an integer value (0x.. for hex)")
    return out


@_said_plainly
def cmd_info(args: argparse.Namespace) -> int:

    with _client(args) as client:
        info = client.info()
    version = f" {info['version']}" if info.get("version") else ""
    head = f"{info['board']} board, {info['daemon']}{version}"
    lines = [shown(head, limit_chars=120)]
    for port in info["ports"]:
        sensor = port["sensor"]
        if sensor is None:
            lines.append(f"  port {port['port']}: no sensor")
        else:
            lines.append(f"  port {port['port']}: {_sensor_line(sensor)}")
    emit(args, info, "\n".join(lines))
    return 0


def _sensor_line(sensor: dict[str, Any]) -> str:
    """``MT9P006 (chip id 0x1801, I2C 0x48, 12-bit, bayer GRBG)``; device text made safe."""
    if sensor.get("chip_id") is not None and sensor.get("i2c_address") is not None:
        where = f"chip id 0x{sensor['chip_id']:04x}, I2C 0x{sensor['i2c_address']:02x}, "
    elif sensor.get("sensor_code") is not None:
        # A stock NC393 names its sensors by SENSOR code: no chip id, no I2C address.
        where = f"SENSOR 0x{sensor['sensor_code']:02x}, "
    else:
        where = ""
    model, bayer = shown(sensor["model"], limit_chars=40), shown(sensor["bayer"], limit_chars=8)
    return f"{model} ({where}{sensor['bits']}-bit, bayer {bayer})"


@_said_plainly
def cmd_params(args: argparse.Namespace) -> int:
    from elphel_host.camera.param_table import daemon_schema, param_rows, table_schema

    with _client(args) as client:
        info = client.info()
        ports = {p["port"]: p for p in info["ports"]}
        if args.sensor_port not in ports:
            have = ", ".join(str(p) for p in sorted(ports))
            raise CameraClientError(f"port {args.sensor_port} does not exist; ports: {have}")
        sensor = ports[args.sensor_port]["sensor"] or {}
        values = client.params(args.sensor_port)
    schema = daemon_schema(args.camera) if info.get("daemon") == "elphel-camd" else table_schema()
    rows = param_rows(schema, values, sensor_code=sensor.get("sensor_code"), port=args.sensor_port)
    table = [("NAME", "VALUE", "UNIT", "RANGE", "MEANING")] + [
        (r.name, "" if r.value is None else str(r.value), r.unit, r.range, r.description)
        for r in rows
    ]
    widths = [max(len(row[i]) for row in table) for i in range(4)]
    lines = [
        f"{n:<{widths[0]}}  {v:>{widths[1]}}  {u:<{widths[2]}}  {a:<{widths[3]}}  {d}".rstrip()
        for n, v, u, a, d in table
    ]
    header = f"port {args.sensor_port}: {sensor.get('model', 'no sensor')}"
    result = {
        "port": args.sensor_port,
        "sensor": sensor.get("model"),
        "params": [r.to_json() for r in rows],
    }
    emit(args, result, "\n".join([header, *lines]))
    return 0


@_said_plainly
def cmd_get(args: argparse.Namespace) -> int:

    with _client(args) as client:
        params = client.params(args.sensor_port, frame=args.frame)
    if args.names:
        args.names = [n.upper() for n in args.names]
        missing = [n for n in args.names if n not in params]
        if missing:
            args.parser.error(
                f"unknown parameter(s) {', '.join(missing)}; known: {', '.join(params)}"
            )
        params = {n: params[n] for n in args.names}
    emit(args, params, "\n".join(f"{k}={v}" for k, v in params.items()))
    return 0


@_said_plainly
def cmd_set(args: argparse.Namespace) -> int:

    changes = _parse_assignments(args.parser, args.assignments)
    with _client(args) as client:
        applied = client.set_params(
            changes, port=args.sensor_port, frame=args.frame, ahead=args.ahead
        )
    now = {k: applied.params[k] for k in changes if k in applied.params}
    human = f"port {args.sensor_port}, frame {applied.frame}: " + " ".join(
        f"{k}={v}" for k, v in now.items()
    )
    emit(args, {"port": args.sensor_port, "frame": applied.frame, "params": applied.params}, human)
    return 0


def _write_capture(
    out: Path, tiff: bytes, png: Path | None, image: Any, *, bayer: str | None
) -> None:
    """Write the TIFF and the PNG preview (when asked): both appear, or neither does."""
    from elphel_host.preview import save_preview

    out.parent.mkdir(parents=True, exist_ok=True)
    with contextlib.ExitStack() as stack:
        stack.enter_context(replacing(out)).write_bytes(tiff)
        if png is not None:
            png.parent.mkdir(parents=True, exist_ok=True)
            save_preview(image, stack.enter_context(replacing(png, keep_suffix=True)), bayer=bayer)


@_said_plainly
def cmd_capture(args: argparse.Namespace) -> int:
    if args.count < 1:
        args.parser.error("--count must be 1 or more")
    with _client(args) as client:
        if args.count == 1 and not args.join:
            frame = client.capture(args.sensor_port, frame=args.frame)
            tiff, image, metadata = frame.tiff, frame.image, frame.metadata
            first, frames = frame.frame, [frame.frame]
        else:
            try:
                burst = client.burst(args.count, port=args.sensor_port, frame=args.frame)
            except PartialBurstError as e:
                if not args.keep_partial or not e.partial.metadata:
                    raise
                return _keep_partial(args, e)
            tiff, image, metadata = burst.tiff, burst.images[0], burst.metadata[0]
            first, frames = burst.frames[0], burst.frames
            if args.join:
                joined = burst.photofinish()
                image = joined.image
                metadata = {
                    **metadata,
                    "shape": list(image.shape),
                    "frames": frames,
                    "pf_strip_times_ns": joined.row_times_ns[:: joined.strip_height].tolist(),
                }
                tiff = _tiff_bytes(image, metadata)
    out: Path = args.out or Path(f"port{args.sensor_port}-frame{first}.tif")
    _write_capture(out, tiff, args.png, image, bayer=metadata.get("bayer"))
    result: dict[str, Any] = {
        "file": str(out),
        "shape": list(image.shape),
        "dtype": str(image.dtype),
        "frames": frames,
        "metadata": metadata,
    }
    if args.png:
        result["png"] = str(args.png)
    h, w = image.shape[:2]
    what = f"frame {first}" if len(frames) == 1 else f"frames {frames[0]}..{frames[-1]}"
    if args.join:
        what = f"photo-finish {what} joined"
    png = f"; preview {result['png']}" if "png" in result else ""
    emit(args, result, f"{what} from port {args.sensor_port}: {w}x{h} {image.dtype} -> {out}{png}")
    return 0


def _keep_partial(args: argparse.Namespace, error: PartialBurstError) -> int:
    """Write the frames of a broken-off burst; fail with the reason."""
    partial = error.partial
    first = int(partial.metadata[0]["frame"])
    out: Path = args.out or Path(f"port{args.sensor_port}-frame{first}.tif")
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, partial.tiff)
    frames = [int(m["frame"]) for m in partial.metadata]
    print(f"elphel: {error}; kept frames {frames[0]}..{frames[-1]} in {out}", file=sys.stderr)
    if args.json:
        emit(args, {"file": str(out), "frames": frames, "complete": False}, "")
    return 1


def _tiff_bytes(image: Any, metadata: dict[str, Any]) -> bytes:
    """A one-page 16-bit TIFF with JSON metadata, as the daemon writes them."""
    import io

    import tifffile

    buffer = io.BytesIO()
    description = strict_json.dumps(metadata, what="the frame's metadata")
    tifffile.imwrite(buffer, image, description=description, metadata=None)
    return buffer.getvalue()


def _event_line(event: CameraEvent) -> str:
    data = event.data
    if event.type == "frame":
        return f"frame  port {data['port']} #{data['frame']} t={data['timestamp_ns']} ns"
    if event.type == "params":
        what = data.get("changes") or {"register": data.get("register")}
        body = " ".join(f"{k}={v}" for k, v in what.items())
        return f"params port {data['port']} @{data['frame']}: {body}"
    text = strict_json.dumps(data, what="the event", sort_keys=True)
    return shown(f"{event.type:6s} {text}", limit_chars=1000)


@_said_plainly
def cmd_watch(args: argparse.Namespace) -> int:

    types = tuple(t.strip() for t in args.types.split(",") if t.strip())
    collected: list[dict[str, Any]] = []
    # A watch outlives a daemon restart: the stream reconnects for up to 30 s.
    with _client(args, retry_s=30.0) as client:
        if args.sensor_port is not None:
            # The event stream would wait for events of a port that never sends any.
            ports = sorted(p["port"] for p in client.info()["ports"])
            if args.sensor_port not in ports:
                raise CameraClientError(
                    f"port {args.sensor_port} does not exist; ports: " + ", ".join(map(str, ports))
                )
        if isinstance(client, NoEventsNoRegisters):
            raise UnsupportedError(
                "camera watch: a stock NC393 has no event stream; follow its frames with "
                "`elphel camera get FRAME` or take them with `elphel camera capture`"
            )
        try:
            for event in client.events(types, port=args.sensor_port, count=args.count):
                entry = {"type": event.type, "id": event.id, **event.data}
                if args.json:
                    collected.append(entry)
                else:
                    print(_event_line(event), flush=True)
        except KeyboardInterrupt:
            if not args.json:
                raise
            print("elphel: interrupted", file=sys.stderr)
    if args.json:
        emit(args, {"events": collected}, "")
    return 0
