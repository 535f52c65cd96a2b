"""The `elphel-camd` command: run the daemon on a board.

Settings come from the command line, then ``ELPHEL_CAMD_*`` environment variables, then
the JSON config file (see `elphel_camd.config`); what the daemon keeps on disk is
`elphel_camd.store`'s.
"""

from __future__ import annotations

import argparse
import inspect
import logging
import socket
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from elphel_camd import __version__
from elphel_camd.boards import board_factories
from elphel_camd.config import ConfigError, DaemonSettings, load_settings
from elphel_camd.events import EventHub
from elphel_camd.service import CameraService
from elphel_camd.store import ParamStore, load_or_create_token

log = logging.getLogger("elphel_camd")


def build_parser() -> argparse.ArgumentParser:
    boards = sorted(board_factories())
    p = argparse.ArgumentParser(
        prog="elphel-camd",
        description="Serve a camera board over REST. Settings: command line, then "
        "ELPHEL_CAMD_* environment (e.g. ELPHEL_CAMD_TOKEN), then the config file.",
    )
    p.add_argument("--version", action="version", version=f"elphel-camd {__version__}")
    p.add_argument("--board", choices=boards, required=True, help="board type")
    p.add_argument(
        "--config",
        type=Path,
        help="JSON settings file (default /etc/elphel-camd/config.json if it exists), e.g. "
        '{"bus_urls": ["/dev/i2c-0"], "host": "0.0.0.0", "read_protected": true}',
    )
    p.add_argument("--bus", action="append", default=[], help="I2C bus URL per port (i2c board)")
    p.add_argument("--host", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=int, help="TCP port (default 8000; 0 = any free port)")
    p.add_argument(
        "--token",
        help="bearer token for writes (default: env ELPHEL_CAMD_TOKEN, else the token "
        "file, created with a random token on first start)",
    )
    p.add_argument("--token-file", type=Path, help="token file (default STATE_DIR/token)")
    p.add_argument("--state-dir", type=Path, help="where the token and parameters are kept")
    p.add_argument(
        "--read-protected",
        action="store_true",
        default=None,
        help="reads need the token too (the health check excepted)",
    )
    return p


# Options named as the setting they override (an option left out is None: not given).
_SETTING_OPTIONS = ("board", "host", "port", "token", "token_file", "state_dir", "read_protected")


def settings_from_args(args: argparse.Namespace) -> DaemonSettings:
    given = {name: getattr(args, name) for name in _SETTING_OPTIONS}
    return load_settings(args.config, bus_urls=args.bus or None, **given)


def build_service(settings: DaemonSettings) -> CameraService:
    """The service of the board named in the settings: sensors, events, saved parameters."""
    options: dict[str, Any] = dict(settings.board_options)
    if settings.bus_urls:
        options["bus_urls"] = list(settings.bus_urls)
    name = settings.board or "i2c"
    factory = board_factories()[name]
    try:
        accepted = set(inspect.signature(factory).parameters)
    except (TypeError, ValueError):
        accepted = set(options)
    unknown = sorted(set(options) - accepted)
    if unknown:
        raise ConfigError(
            f"board {name}: unknown option(s) {', '.join(unknown)}; "
            f"allowed: {', '.join(sorted(accepted)) or 'none'} or a daemon setting"
        )
    try:
        board = factory(**options)
    except (TypeError, ValueError, OSError) as e:
        raise ConfigError(f"board {name}: {e}") from e
    store = (
        ParamStore(settings.params_path, sync_each=settings.params_fsync_each)
        if settings.persist_params
        else None
    )
    try:
        return CameraService(board, events=EventHub(settings.event_queue), store=store)
    except BaseException:
        board.close()
        raise


build_camera = build_service  # the old name


def main(argv: Sequence[str] | None = None) -> int:
    from elphel_camd.api import create_app
    from elphel_camd.serving import GracefulServer, server_config

    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    try:
        settings = settings_from_args(args)
        if settings.token is not None and settings.token.get_secret_value():
            token = settings.token.get_secret_value()
        else:
            token = load_or_create_token(settings.token_path)
            log.info("bearer token from %s", settings.token_path)
        service = build_service(settings)
    except (ConfigError, OSError) as e:
        print(f"elphel-camd: {e}", file=sys.stderr)
        return 1
    # IPPROTO_TCP explicitly: asyncio sets TCP_NODELAY only on sockets that name it, and
    # without it every answer waits ~40 ms for the client's delayed ACK.
    family = socket.AF_INET6 if ":" in settings.host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((settings.host, settings.port))
        sock.listen(128)
        host, port = sock.getsockname()[:2]
        app = create_app(
            service,
            token=token,
            read_protected=settings.read_protected,
            max_body_bytes=settings.max_body_bytes,
        )
        # Request/idle timeouts and a bounded number of connections; a shutdown ends
        # the event streams first (elphel_camd.serving).
        config = server_config(app, log_level=settings.log_level, access_log=settings.access_log)
        log.info("listening on http://%s:%d", host, port)
        GracefulServer(config, on_shutdown=[service.events.close]).run(sockets=[sock])
    except OSError as e:
        print(
            f"elphel-camd: cannot listen on {settings.host}:{settings.port}: {e}", file=sys.stderr
        )
        return 1
    finally:
        sock.close()
        service.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
