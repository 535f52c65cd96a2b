"""The `elphel-camd` command: run the daemon on a board."""

from __future__ import annotations

import argparse
import json
import logging
import os
import secrets
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from elphel_camd import __version__
from elphel_camd.board import Camera, board_factories


def build_parser() -> argparse.ArgumentParser:
    boards = sorted(board_factories())
    p = argparse.ArgumentParser(prog="elphel-camd", description="Serve a camera board over REST.")
    p.add_argument("--version", action="version", version=f"elphel-camd {__version__}")
    p.add_argument("--board", choices=boards, required=True, help="board type")
    p.add_argument(
        "--config",
        type=Path,
        help='JSON file of board options, e.g. {"bus_urls": ["/dev/i2c-0"]} for the i2c board',
    )
    p.add_argument("--bus", action="append", default=[], help="I2C bus URL per port (i2c board)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default loopback)")
    p.add_argument("--port", type=int, default=8000, help="TCP port (0 = any free port)")
    p.add_argument(
        "--token",
        default=os.environ.get("ELPHEL_CAMD_TOKEN"),
        help="bearer token for writes (default: env ELPHEL_CAMD_TOKEN, else a random one)",
    )
    return p


def main(argv: Sequence[str] | None = None) -> int:
    import uvicorn

    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    options: dict[str, Any] = {}
    if args.config is not None:
        try:
            options = json.loads(args.config.read_text())
        except (OSError, json.JSONDecodeError) as e:
            print(f"elphel-camd: cannot read config {args.config}: {e}", file=sys.stderr)
            return 1
    if args.bus:
        options["bus_urls"] = args.bus
    token = args.token or secrets.token_urlsafe(24)
    try:
        board = board_factories()[args.board](**options)
    except (TypeError, ValueError, OSError) as e:
        print(f"elphel-camd: board {args.board}: {e}", file=sys.stderr)
        return 1
    from elphel_camd.api import create_app

    camera = Camera(board)
    if not args.token:
        print(f"elphel-camd: token {token}", file=sys.stderr)
    try:
        uvicorn.run(
            create_app(camera, token=token), host=args.host, port=args.port, log_level="info"
        )
    finally:
        camera.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
