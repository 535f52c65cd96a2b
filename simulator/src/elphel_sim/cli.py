"""The `elphel-sim` command."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from elphel_sim import __version__
from elphel_sim.render.optics import MAX_LENS_BLUR_PX, LensBlur
from elphel_sim.scenarios import SCENARIOS


def tcp_port(text: str) -> int:
    """A TCP port for argparse: 0 (a free port) to 65535."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}; allowed: 0 (a free port) to 65535")
    return value


def lens_blur(text: str) -> LensBlur:
    """A lens blur for argparse: ``C`` or ``C:E`` (sigma in sensor px)."""
    try:
        return LensBlur.parse(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}; allowed: C or C:E, sigmas 0..{MAX_LENS_BLUR_PX:g} sensor pixels"
        ) from None


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="elphel-sim", description="Simulated Elphel rig.")
    p.add_argument("--version", action="version", version=f"elphel-sim {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    up = sub.add_parser("up", help="serve a simulated camera board (and stage) until stopped")
    up.add_argument("--scenario", default="default", choices=sorted(SCENARIOS))
    up.add_argument("--seed", type=int, default=0, help="seed of every noise source")
    up.add_argument(
        "--camera-port", type=tcp_port, default=0, help="camera REST port (0 = free port)"
    )
    up.add_argument("--stage-port", type=tcp_port, default=0, help="stage TCP port (0 = free port)")
    up.add_argument(
        "--firmware",
        choices=("camd", "elphel"),
        default="camd",
        help="camd: elphel-camd's REST API (default); elphel: a stock NC393's parsedit.php "
        "on the camera port and imgsrv on four consecutive free ports",
    )
    up.add_argument(
        "--public-reads",
        action="store_true",
        help="camd firmware: answer reads without the token, as elphel-camd --public-reads",
    )
    up.add_argument(
        "--lens-blur",
        type=lens_blur,
        default=None,
        metavar="C[:E]",
        help="the lenses blur the image: a Gaussian of sigma C sensor pixels on the optical "
        "axis, growing with the squared distance from it to E at the farthest corner "
        f"(0..{MAX_LENS_BLUR_PX:g}; default: a perfectly sharp lens)",
    )
    up.add_argument("--json", action="store_true", help="first stdout line: one JSON object")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from elphel_sim.launcher import up

    try:
        return up(
            scenario=args.scenario,
            seed=args.seed,
            camera_port=args.camera_port,
            stage_port=args.stage_port,
            as_json=args.json,
            firmware=args.firmware,
            public_reads=args.public_reads,
            lens_blur=args.lens_blur,
        )
    except (OSError, ValueError) as e:
        print(f"elphel-sim: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
