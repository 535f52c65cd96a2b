"""The `elphel-camd` command: run the daemon on a board, or rotate its token.

``elphel-camd --board B ...`` serves the board (or the one the config file names: the
mixed board's ports are listed there); ``elphel-camd token rotate`` writes a new
random token to the token file (0600), which a running daemon reads at its next request
(the old token is refused from then on); ``elphel-camd vospi-record`` records a Lepton's
VoSPI stream for replay (`elphel_camd.cli_vospi`). Settings come from the command line, then
``ELPHEL_CAMD_*`` environment variables, then the JSON config file (see
`elphel_camd.config`); what the daemon keeps on disk is `elphel_camd.store`'s.
"""

from __future__ import annotations

import argparse
import gc
import inspect
import logging
import socket
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from elphel_camd import __version__
from elphel_camd.boards import board_factories
from elphel_camd.config import ConfigError, DaemonSettings, load_settings
from elphel_camd.events import EventHub
from elphel_camd.service import CameraService
from elphel_camd.store import ParamStore, load_or_create_token, new_token, write_atomic

if TYPE_CHECKING:
    from elphel_camd.api.deps import TokenSource

log = logging.getLogger("elphel_camd")


def build_parser() -> argparse.ArgumentParser:
    boards = sorted(board_factories())
    p = argparse.ArgumentParser(
        prog="elphel-camd",
        description="Serve a camera board over REST. Settings: command line, then "
        "ELPHEL_CAMD_* environment (e.g. ELPHEL_CAMD_TOKEN), then the config file.",
    )
    p.add_argument("--version", action="version", version=f"elphel-camd {__version__}")
    p.add_argument(
        "--board",
        choices=boards,
        help='board type (or "board" in the config file; the mixed board\'s ports are '
        "listed there)",
    )
    p.add_argument(
        "--config",
        type=Path,
        help="JSON settings file (default /etc/elphel-camd/config.json if it exists), e.g. "
        '{"bus_urls": ["/dev/i2c-0"], "host": "0.0.0.0", "public_reads": true}, or '
        '{"board": "mixed", "ports": [{"video": "/dev/video0"}, {"vospi": "/dev/spidev0.0"}]}',
    )
    p.add_argument(
        "--bus",
        action="append",
        default=[],
        help="I2C bus URL per port (i2c board; v4l2 board: the bus of the k-th --video's "
        "sensor when the project's own driver programs it; lepton board: its CCI bus)",
    )
    p.add_argument(
        "--video",
        action="append",
        default=[],
        help="V4L2 capture node per port (v4l2 board), e.g. /dev/video0",
    )
    p.add_argument(
        "--sensor",
        help="v4l2 board: the kernel driver of the sensor (e.g. imx219), for its gain laws",
    )
    p.add_argument(
        "--vospi",
        help="lepton board: the Lepton's spidev node (/dev/spidevB.C), or a file or FIFO "
        "with its VoSPI bytes (a recording)",
    )
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
        "--public-reads",
        action="store_true",
        default=None,
        help="answer reads without the token (by default every request but /health needs it)",
    )
    p.add_argument(
        "--allow-host",
        action="append",
        dest="allowed_hosts",
        help="a host name clients may use in Host besides IP addresses and localhost "
        "(repeat; * = any, behind a proxy that checks it)",
    )
    p.add_argument(
        "--cors-origin",
        action="append",
        dest="cors_origins",
        help="an origin whose browser pages may call the API, e.g. https://lab.example (repeat)",
    )
    p.add_argument("--tls-cert", type=Path, help="TLS certificate (PEM): serve https")
    p.add_argument("--tls-key", type=Path, help="TLS private key (PEM) of --tls-cert")
    return p


# Options named as the setting they override (an option left out is None: not given).
_SETTING_OPTIONS = (
    "board",
    "sensor",
    "host",
    "port",
    "token",
    "token_file",
    "state_dir",
    "public_reads",
    "allowed_hosts",
    "cors_origins",
    "tls_cert",
    "tls_key",
)


def build_token_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="elphel-camd token",
        description="Manage the daemon's bearer token file.",
    )
    sub = p.add_subparsers(dest="action", required=True)
    rotate = sub.add_parser(
        "rotate",
        help="replace the token file with a new random token; a running daemon uses it "
        "from its next request on and refuses the old one",
    )
    rotate.add_argument("--config", type=Path, help="JSON settings file")
    rotate.add_argument("--token-file", type=Path, help="token file (default STATE_DIR/token)")
    rotate.add_argument("--state-dir", type=Path, help="the daemon's state directory")
    rotate.add_argument(
        "--quiet", action="store_true", help="print nothing (else the new token on stdout)"
    )
    return p


def token_main(argv: Sequence[str]) -> int:
    """``elphel-camd token rotate``: a new token in the token file, 0600, atomically."""
    args = build_token_parser().parse_args(argv)
    try:
        settings = load_settings(args.config, token_file=args.token_file, state_dir=args.state_dir)
    except ConfigError as e:
        print(f"elphel-camd token: {e}", file=sys.stderr)
        return 1
    path = settings.token_path
    token = new_token()
    try:
        write_atomic(path, (token + "\n").encode(), mode=0o600)
    except OSError as e:
        print(f"elphel-camd token: cannot write {path}: {e}", file=sys.stderr)
        return 1
    print(f"elphel-camd token: new token written to {path}", file=sys.stderr)
    if settings.token is not None and settings.token.get_secret_value():
        print(
            "elphel-camd token: note: ELPHEL_CAMD_TOKEN is set; a daemon started with it "
            "(or with --token) does not read the file",
            file=sys.stderr,
        )
    if not args.quiet:
        print(token)
    return 0


def settings_from_args(args: argparse.Namespace) -> DaemonSettings:
    given = {name: getattr(args, name) for name in _SETTING_OPTIONS}
    settings = load_settings(
        args.config, bus_urls=args.bus or None, video=args.video or None, **given
    )
    if args.vospi is not None:
        settings.board_options["vospi"] = args.vospi
    return settings


def build_service(settings: DaemonSettings) -> CameraService:
    """The service of the board named in the settings: sensors, events, saved parameters."""
    options: dict[str, Any] = dict(settings.board_options)
    if settings.bus_urls:
        options["bus_urls"] = list(settings.bus_urls)
    if settings.video:
        options["video"] = list(settings.video)
    if settings.sensor:
        options["sensor"] = settings.sensor
    if settings.board is None:
        raise ConfigError('no board: give --board or "board" in the config file')
    name = settings.board
    factories = board_factories()
    if name not in factories:
        raise ConfigError(f"board {name!r}; allowed: {', '.join(sorted(factories))}")
    factory = factories[name]
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


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["token"]:
        return token_main(argv[1:])
    if argv[:1] == ["vospi-record"]:
        from elphel_camd.cli_vospi import record_main

        return record_main(argv[1:])
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    try:
        settings = settings_from_args(args)
        if (settings.tls_cert is None) != (settings.tls_key is None):
            raise ConfigError("give both --tls-cert and --tls-key (or neither)")
        token = token_source(settings)
        service = build_service(settings)
    except (ConfigError, OSError, ValueError) as e:
        print(f"elphel-camd: {e}", file=sys.stderr)
        return 1
    try:
        serve(settings, service, token)
    except OSError as e:
        print(
            f"elphel-camd: cannot listen on {settings.host}:{settings.port}: {e}", file=sys.stderr
        )
        return 1
    finally:
        service.close()
    return 0


def token_source(settings: DaemonSettings) -> TokenSource:
    """The daemon's token: the configured one, else the token file (created if missing)."""
    from elphel_camd.api.deps import TokenSource

    if settings.token is not None and settings.token.get_secret_value():
        return TokenSource(settings.token.get_secret_value())
    load_or_create_token(settings.token_path)
    log.info("bearer token from %s (re-read when it changes)", settings.token_path)
    return TokenSource(path=settings.token_path)


def serve(settings: DaemonSettings, service: CameraService, token: TokenSource) -> None:
    """Serve the API of ``service`` as the settings say until the daemon is stopped."""
    from elphel_camd.api import create_app
    from elphel_camd.serving import GracefulServer, http_stack, server_config

    sock = listening_socket(settings.host, settings.port)
    try:
        app = create_app(
            service,
            token=token,
            public_reads=settings.public_reads,
            max_body_bytes=settings.max_body_bytes,
            stream_idle_s=settings.stream_idle_s,
            allowed_hosts=[settings.host, *settings.allowed_hosts],
            cors_origins=settings.cors_origins,
        )
        tls: dict[str, Any] = {}
        if settings.tls_cert is not None and settings.tls_key is not None:
            tls = {"ssl_certfile": str(settings.tls_cert), "ssl_keyfile": str(settings.tls_key)}
        # Request/idle timeouts and a bounded number of connections; a shutdown ends
        # the event streams first (elphel_camd.serving).
        config = server_config(
            app,
            log_level=settings.log_level,
            access_log=settings.access_log,
            max_head_bytes=settings.max_header_bytes,
            **tls,
        )
        host, port = sock.getsockname()[:2]
        log.info(
            "listening on %s://%s:%d (reads %s; HTTP: %s)",
            "https" if tls else "http",
            host,
            port,
            "public" if settings.public_reads else "need the token",
            http_stack(config),
        )
        # What exists now (modules, the board, the app) lives as long as the daemon: kept
        # out of the cyclic garbage collector's sight, a full collection (which stops
        # every request) looks only at what came since.
        gc.freeze()
        GracefulServer(config, on_shutdown=[service.events.close]).run(sockets=[sock])
    finally:
        sock.close()


def listening_socket(host: str, port: int) -> socket.socket:
    """A TCP socket bound to ``host:port`` and listening (OSError if it cannot be)."""
    # IPPROTO_TCP explicitly: asyncio sets TCP_NODELAY only on sockets that name it, and
    # without it every answer waits ~40 ms for the client's delayed ACK.
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, port))
        sock.listen(128)
    except OSError:
        sock.close()
        raise
    return sock


if __name__ == "__main__":
    sys.exit(main())
