"""`elphel camera ...`: talk to a camera daemon."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

from elphel_host.camera.client import CameraClient


def register(sub: Any) -> None:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "--url",
        default=os.environ.get("ELPHEL_CAMERA_URL"),
        help="daemon URL (env ELPHEL_CAMERA_URL)",
    )
    common.add_argument(
        "--token",
        default=os.environ.get("ELPHEL_CAMERA_TOKEN"),
        help="bearer token (env ELPHEL_CAMERA_TOKEN)",
    )
    p = sub.add_parser("camera", help="camera daemon: info, capture")
    cmd = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    info = cmd.add_parser(
        "info", parents=[common], help="board, daemon version, ports and their sensors"
    )
    info.add_argument("--json", action="store_true", help="print one JSON object")
    info.set_defaults(func=cmd_info)

    cap = cmd.add_parser(
        "capture", parents=[common], help="capture the next frame of a port as a 16-bit TIFF"
    )
    cap.add_argument("--port", type=int, default=0, help="sensor port (default 0)")
    cap.add_argument("--out", type=Path, help="TIFF path (default: portP-frameN.tif)")
    cap.add_argument("--png", type=Path, help="also write an 8-bit PNG preview here")
    cap.add_argument("--json", action="store_true", help="print one JSON object")
    cap.set_defaults(func=cmd_capture, parser=cap)
    info.set_defaults(parser=info)


def _client(args: argparse.Namespace) -> CameraClient:
    if not args.url:
        args.parser.error("no camera URL: give --url or set ELPHEL_CAMERA_URL")
    return CameraClient(args.url, args.token)


def cmd_info(args: argparse.Namespace) -> int:
    from elphel_host.cli import emit

    with _client(args) as client:
        info = client.info()
    lines = [f"{info['board']} board, {info['daemon']} {info['version']}"]
    for port in info["ports"]:
        sensor = port["sensor"]
        if sensor is None:
            lines.append(f"  port {port['port']}: no sensor")
        else:
            lines.append(
                f"  port {port['port']}: {sensor['model']} (chip id 0x{sensor['chip_id']:04x}, "
                f"I2C 0x{sensor['i2c_address']:02x}, {sensor['bits']}-bit, bayer {sensor['bayer']})"
            )
    emit(args, info, "\n".join(lines))
    return 0


def cmd_capture(args: argparse.Namespace) -> int:
    from elphel_host.cli import emit
    from elphel_host.preview import save_preview

    with _client(args) as client:
        frame = client.capture(args.port)
    out: Path = args.out or Path(f"port{args.port}-frame{frame.frame}.tif")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(frame.tiff)
    result: dict[str, Any] = {
        "file": str(out),
        "shape": list(frame.image.shape),
        "dtype": str(frame.image.dtype),
        "metadata": frame.metadata,
    }
    if args.png:
        result["png"] = str(save_preview(frame.image, args.png, bayer=frame.metadata.get("bayer")))
    h, w = frame.image.shape[:2]
    emit(
        args,
        result,
        f"frame {frame.frame} from port {args.port}: {w}x{h} {frame.image.dtype} -> {out}",
    )
    return 0
