"""What every `elphel` subcommand shares: printing results and the common options.

The option helpers give one spelling per idea across subcommands: ``--camera`` for a
camera URL, ``--stage`` for a stage URL, ``--sensor-port`` for a sensor port of the
camera. Older spellings (``--url``, ``--port``) stay accepted as aliases so scripts keep
working; they set the same value.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

CAMERA_URL_ENV = "ELPHEL_CAMERA_URL"
CAMERA_TOKEN_ENV = "ELPHEL_CAMERA_TOKEN"
STAGE_URL_ENV = "ELPHEL_STAGE_URL"
DEFAULT_STAGE_MODEL = Path.home() / ".config" / "elphel" / "stage-model.json"


def emit(args: argparse.Namespace, result: dict[str, Any], human: str) -> None:
    """Print a command's result: one JSON object with --json, else the human text."""
    if getattr(args, "json", False):
        print(json.dumps(result, sort_keys=True))
    else:
        print(human)


def fail(message: str) -> int:
    """Print the one-line error of a failed command on stderr; its exit code, 1."""
    print(f"elphel: {message}", file=sys.stderr)
    return 1


def add_json_option(parser: Any) -> None:
    """``--json``: print exactly one JSON object on stdout."""
    parser.add_argument("--json", action="store_true", help="print one JSON object")


BAR_WIDTH = 24


def _clock(seconds: float) -> str:
    m, sec = divmod(round(seconds), 60)
    h, m = divmod(m, 60)
    return f"{h}:{m:02d}:{sec:02d}" if h else f"{m}:{sec:02d}"


class ProgressLine:
    """Progress of a long command on stderr: one updating line on a terminal, else a line each.

    Given ``done`` and ``total``, the line carries the rate and the time left; on a
    terminal, rich draws a bar before it. stdout stays for the result (one JSON object
    with --json), so progress never mixes with it.
    """

    def __init__(
        self, stream: TextIO | None = None, *, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._open = False
        self._clock = clock
        self._start: tuple[float, int] | None = None

    def rate_text(self, done: int, total: int) -> str:
        """``"2.0/s, 0:04 left"`` since the first update (empty until something is done)."""
        now = self._clock()
        if self._start is None or done < self._start[1]:
            self._start = (now, done)
        t0, d0 = self._start
        if now <= t0 or done <= d0:
            return ""
        rate = (done - d0) / (now - t0)
        return f"{rate:.3g}/s, {_clock(max(total - done, 0) / rate)} left"

    def _bar(self, done: int, total: int) -> str:
        """The progress bar of rich, ``BAR_WIDTH`` cells, as terminal text (colours included)."""
        from rich.console import Console
        from rich.progress_bar import ProgressBar

        console = Console(
            file=io.StringIO(), force_terminal=True, color_system="standard", width=BAR_WIDTH
        )
        with console.capture() as captured:
            console.print(
                ProgressBar(total=total, completed=min(max(done, 0), total), width=BAR_WIDTH),
                end="",
            )
        return captured.get()

    def update(self, text: str, *, done: int | None = None, total: int | None = None) -> None:
        """Show ``text`` as the current state (replacing the previous one on a terminal).

        With ``done`` of ``total`` (``text`` names the counts), the rate and the time
        left follow it, and a terminal shows a bar before it.
        """
        if done is not None and total:
            rate = self.rate_text(done, total)
            if rate:
                text = f"{text} ({rate})"
            if self.tty:
                text = f"{self._bar(done, total)} {text}"
        if self.tty:
            self.stream.write(f"\r{text}\x1b[K")
            self._open = True
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def end(self) -> None:
        """Finish the updating line (a no-op when not on a terminal)."""
        if self._open:
            self.stream.write("\n")
            self.stream.flush()
            self._open = False

    def say(self, prefix: str) -> Callable[[str], None]:
        """A callback printing ``prefix + message`` as a line of its own."""

        def print_line(message: str) -> None:
            self.end()
            self.stream.write(f"{prefix}{message}\n")
            self.stream.flush()

        return print_line


def _alias_note(aliases: tuple[str, ...]) -> str:
    return f"; {', '.join(aliases)} is the older spelling" if aliases else ""


def _add_url_option(parser: Any, flag: str, aliases: tuple[str, ...], env: str, what: str) -> None:
    parser.add_argument(
        flag,
        *aliases,
        dest=flag.removeprefix("--"),
        default=os.environ.get(env),
        metavar="URL",
        help=f"{what} (env {env}{_alias_note(aliases)})",
    )


def add_camera_options(parser: Any, *, aliases: tuple[str, ...] = ()) -> None:
    """``--camera URL`` and ``--token T``, defaulting to ELPHEL_CAMERA_URL / _TOKEN.

    ``aliases`` are older spellings of ``--camera`` kept for scripts (``--url``).
    """
    _add_url_option(
        parser,
        "--camera",
        aliases,
        CAMERA_URL_ENV,
        "camera URL: http://HOST:PORT (elphel-camd) or nc393://HOST[:PORT][?imgsrv=BASE] "
        "(a stock NC393)",
    )
    parser.add_argument(
        "--token",
        default=os.environ.get(CAMERA_TOKEN_ENV),
        help=f"elphel-camd's bearer token; a stock NC393 needs none (env {CAMERA_TOKEN_ENV})",
    )


def add_stage_option(parser: Any, *, aliases: tuple[str, ...] = ()) -> None:
    """``--stage URL`` (a pyserial URL), defaulting to ELPHEL_STAGE_URL."""
    _add_url_option(parser, "--stage", aliases, STAGE_URL_ENV, "pyserial URL of the stage")


def add_stage_model_option(parser: Any, *, help: str = "stage calibration file") -> None:
    """``--model PATH``: the stage calibration (``elphel stage calibrate`` writes it)."""
    parser.add_argument("--model", type=Path, default=DEFAULT_STAGE_MODEL, help=help)


def add_sensor_port_option(parser: Any, *, default: int | None = 0, help: str = "") -> None:
    """``--sensor-port N`` (``--port N`` is the older spelling), a port of the camera."""
    parser.add_argument(
        "--sensor-port",
        "--port",
        dest="sensor_port",
        type=int,
        default=default,
        metavar="N",
        help=(help or f"sensor port of the camera (default {default})")
        + "; --port is the older spelling",
    )
