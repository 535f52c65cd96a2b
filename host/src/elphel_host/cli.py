"""The `elphel` command: one entry point, one subcommand per area.

Each area module exposes ``register(subparsers)``, which adds its subcommand and sets
``func`` on the parser to a function ``(args) -> int``. Conventions for every command:
``--json`` prints exactly one JSON object on stdout; exit 0 on success, 1 on failure with
a one-line error on stderr, 2 on a usage error (argparse's own code).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from PIL import Image

from elphel_host import __version__
from elphel_host.errors import ElphelError
from elphel_host.shown import shown

# Area modules, each with register(subparsers). Add a module here to add a subcommand.
AREAS = (
    "elphel_host.camera.cli",
    "elphel_host.stage.cli",
    "elphel_host.burst.cli",
    "elphel_host.mfsr.cli",
    "elphel_host.tp.cli",
    "elphel_host.cloud.cli",
    "elphel_host.depth.cli",
    "elphel_host.recordings.cli",
    "elphel_host.calibrate.cli",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="elphel",
        description="Control Elphel-style cameras and a burst stage; process their images.",
    )
    parser.add_argument("--version", action="version", version=f"elphel {__version__}")
    sub = parser.add_subparsers(dest="area", required=True, metavar="AREA")
    for name in AREAS:
        importlib.import_module(name).register(sub)
    return parser


# Errors that bad input (a device's answer, a file) raises inside libraries: what a
# user can do about them is in the message, and a traceback would only hide it.
_FAILURES: tuple[type[BaseException], ...] = (
    ElphelError,
    OSError,
    ValueError,
    Image.DecompressionBombError,
    MemoryError,
    RecursionError,
)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code: int = args.func(args)
    except KeyboardInterrupt as e:
        said = f": {e}" if str(e) else ""  # what was kept and how to resume, when known
        print(f"elphel: interrupted{said}", file=sys.stderr)
        return 130
    except _FAILURES as e:
        print(f"elphel: {_one_line(e)}", file=sys.stderr)
        return 1
    return code


def _one_line(error: BaseException) -> str:
    """The error's message, terminal-safe and on one line (its type when it has none)."""
    text = str(error) or type(error).__name__
    if isinstance(error, Image.DecompressionBombError | MemoryError | RecursionError):
        text = f"{type(error).__name__}: {text}"
    return shown(text, limit_chars=500)


if __name__ == "__main__":
    sys.exit(main())
