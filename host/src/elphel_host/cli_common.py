"""What every `elphel` subcommand shares: printing results and the common options.

The option helpers give one spelling per idea across subcommands: ``--camera`` for a
camera URL, ``--stage`` for a stage URL, ``--sensor-port`` for a sensor port of the
camera (``--port`` is only ever a TCP port).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

from elphel_host.shown import shown
from elphel_host.strict_json import report_dumps

CAMERA_URL_ENV = "ELPHEL_CAMERA_URL"
CAMERA_TOKEN_ENV = "ELPHEL_CAMERA_TOKEN"
STAGE_URL_ENV = "ELPHEL_STAGE_URL"


def emit(args: argparse.Namespace, result: dict[str, Any], human: str) -> None:
    """Print a command's result: one JSON object with --json, else the human text."""
    if getattr(args, "json", False):
        print(report_dumps(result, sort_keys=True))
    else:
        print(human)


def fail(message: str) -> int:
    """Print the one-line error of a failed command on stderr; its exit code, 1."""
    print(f"elphel: {shown(message, limit_chars=500)}", file=sys.stderr)
    return 1


def add_json_option(parser: Any) -> None:
    """``--json``: print exactly one JSON object on stdout."""
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _add_url_option(parser: Any, flag: str, env: str, what: str) -> None:
    parser.add_argument(
        flag,
        dest=flag.removeprefix("--"),
        default=os.environ.get(env),
        metavar="URL",
        help=f"{what} (env {env})",
    )


def add_camera_options(parser: Any) -> None:
    """``--camera URL`` and ``--token T``, defaulting to ELPHEL_CAMERA_URL / _TOKEN."""
    _add_url_option(
        parser,
        "--camera",
        CAMERA_URL_ENV,
        "camera URL: http://HOST:PORT (elphel-camd) or nc393://HOST[:PORT][?imgsrv=BASE] "
        "(a stock NC393)",
    )
    parser.add_argument(
        "--token",
        default=os.environ.get(CAMERA_TOKEN_ENV),
        help=f"elphel-camd's bearer token; a stock NC393 needs none (env {CAMERA_TOKEN_ENV})",
    )


def fusion_scale(text: str) -> int:
    """An argparse ``type`` for a fusion's ``--scale``: a bad one is a usage error (exit 2)."""
    from elphel_host.mfsr.scale import allowed_scales, check_scale

    try:
        return check_scale(int(text))
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"scale={text!r}; allowed: {allowed_scales()}") from e


def add_stage_option(parser: Any) -> None:
    """``--stage URL`` (a pyserial URL), defaulting to ELPHEL_STAGE_URL."""
    _add_url_option(parser, "--stage", STAGE_URL_ENV, "pyserial URL of the stage")


def add_stage_model_option(parser: Any, *, help: str = "stage calibration file") -> None:
    """``--model PATH``: the stage calibration (``elphel stage calibrate`` writes it).

    Without it, the stage's own file is used: named by the serial the stage reports.
    """
    parser.add_argument(
        "--model",
        type=Path,
        default=None,
        metavar="PATH",
        help=f"{help} (default: $XDG_CONFIG_HOME/elphel/stages/SERIAL.json, "
        "XDG_CONFIG_HOME defaulting to ~/.config, SERIAL the one the stage reports)",
    )


def add_sensor_port_option(parser: Any, *, default: int | None = 0, help: str = "") -> None:
    """``--sensor-port N``, a sensor port of the camera."""
    parser.add_argument(
        "--sensor-port",
        dest="sensor_port",
        type=int,
        default=default,
        metavar="N",
        help=help or f"sensor port of the camera (default {default})",
    )
