"""`elphel-sim up`: serve a simulated rig (camera REST, inspection endpoint) until stopped.

The camera board is served by the real daemon application (elphel_camd.api) on top of
the simulated board. A second, loopback-only server is the simulator's own inspection
endpoint (``sim_url``): it tells the truth the host cannot see, for tests and demos,
and injects faults (`elphel_sim.faults`: ``{sim_url}/faults``).
"""

from __future__ import annotations

import asyncio
import io
import json
import signal
import socket
import sys
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import tifffile
from fastapi import APIRouter, FastAPI, HTTPException, Response

from elphel_camd.api import create_app
from elphel_camd.errors import FrameNotAvailableError, PortError
from elphel_camd.service import CameraService
from elphel_camd.serving import GracefulServer, server_config
from elphel_camd.store import new_token
from elphel_host.cloud.ply import ply_bytes
from elphel_sim.board import SimCameraBoard
from elphel_sim.calib_board import board_router
from elphel_sim.faults import fault_router
from elphel_sim.lepton_vospi import VoSPIPort, lepton_ports, vospi_board, vospi_fault_router
from elphel_sim.port_view import PortView
from elphel_sim.quad import QuadScene
from elphel_sim.quad_truth import TileTruth, tile_truth
from elphel_sim.relief import depth_map, surface_cloud
from elphel_sim.render.optics import SHARP, LensBlur
from elphel_sim.scenarios import build
from elphel_sim.stage_server import SimStage
from elphel_sim.stock.firmware import StockFirmware
from elphel_sim.stock.server import consecutive_sockets, imgsrv_app, parsedit_app


def create_sim_app(board: SimCameraBoard, stage: SimStage | None = None) -> FastAPI:
    """The inspection API: what the simulator knows to be true, and its fault hooks.

    A calibration scenario adds ``/board`` (`elphel_sim.calib_board.board_router`).
    """
    app = FastAPI(title="elphel-sim inspection")
    app.include_router(fault_router(board, stage))
    app.include_router(rig_router(board, stage))
    app.include_router(quad_router(board))
    if board.calib is not None:
        app.include_router(board_router(board.world, board.calib))
    return app


def rig_router(board: SimCameraBoard, stage: SimStage | None) -> APIRouter:
    """``/stage``, ``/ports/{port}/frames/{frame}`` and ``/world``: the rig's truth."""
    router = APIRouter()

    @router.get("/stage")
    def stage_state() -> dict[str, Any]:
        """The carriage's true position and the simulated mechanics."""
        if stage is None:
            raise HTTPException(status_code=404, detail="this rig has no simulated stage")
        return stage.sim_state()

    @router.get("/ports/{port}/frames/{frame}")
    def frame_truth(port: int, frame: int) -> dict[str, Any]:
        """A recorded frame's true time and camera pose (carriage position)."""
        try:
            return board.sim_frame_truth(port, frame)
        except (PortError, FrameNotAvailableError) as e:
            raise HTTPException(status_code=404, detail=str(e)) from e

    @router.get("/world")
    def world() -> dict[str, Any]:
        """Carriage position and the scene's planes."""
        w = board.world
        return {
            "carriage_mm": w.rig.carriage_mm,
            "axis": list(w.rig.axis),
            "planes": [
                {"origin": list(p.origin), "albedo_rgb": list(p.albedo_rgb)} for p in w.scene.planes
            ],
            "ports": {
                str(port): {"model": spec.model, "mount": spec.mount}
                for port, spec in board.ports.items()
            },
        }

    return router


def quad_scene(board: SimCameraBoard) -> QuadScene:
    """The board's quad scene; a 404 when the scenario has no quad camera."""
    if board.quad is None:
        raise HTTPException(
            status_code=404, detail="this scenario has no quad camera (try --scenario quad)"
        )
    return board.quad


def quad_geometry(scene: QuadScene) -> dict[str, Any]:
    """The quad camera's geometry and the scene's regions with their disparities."""
    rig = scene.rig
    window = {"window": scene.window} if scene.window else {}
    return window | {
        "cameras": [
            {"port": i, "position": list(position)} for i, position in enumerate(rig.positions)
        ],
        "optics": {
            "focal_length_mm": rig.focal_length_mm,
            "pixel_pitch_um": rig.pixel_pitch_um,
            "baseline_mm": rig.baseline_mm,
        },
        "image_size": [rig.width, rig.height],
        "bayer": rig.bayer,
        "regions": [
            {
                "name": r.name,
                "textured": r.textured,
                "depth_mm": float(r.plane.origin[2]),
                "disparity_px": float(rig.disparity_px(r.plane.origin[2])),
            }
            for r in scene.regions
        ],
    }


def tile_truth_document(t: TileTruth) -> dict[str, Any]:
    """``t`` as JSON: tile grid, region names and the per-tile maps (rows are tiles-Y)."""
    return {
        "tile_size": 16,
        "tile_stride": 8,
        "tiles_x": int(t.disparity.shape[1]),
        "tiles_y": int(t.disparity.shape[0]),
        "names": list(t.names),
        "disparity": t.disparity.tolist(),
        "label": t.label.tolist(),
        "interior": t.interior.tolist(),
        "textured": t.textured.tolist(),
    }


def quad_offset_mm(board: SimCameraBoard, carriage_mm: float | None) -> tuple[float, float, float]:
    """Where the quad is: carried by the stage (quad-rig) or fixed (quad)."""
    rig = board.world.rig
    mount = rig.mounts.get("cam0")
    if mount is None or not mount.on_stage:
        return (0.0, 0.0, 0.0)
    c = rig.carriage_mm if carriage_mm is None else carriage_mm
    norm = sum(a * a for a in rig.axis) ** 0.5
    return (c * rig.axis[0] / norm, c * rig.axis[1] / norm, c * rig.axis[2] / norm)


def quad_router(board: SimCameraBoard) -> APIRouter:
    """``/quad``, ``/quad/truth``, ``/quad/reference.ply``, ``/quad/depth/{camera}``."""
    router = APIRouter()
    lock = threading.Lock()
    truths: list[TileTruth] = []  # computed on the first request (about a second)

    @router.get("/quad")
    def quad() -> dict[str, Any]:
        """The quad camera's geometry and the scene's regions with their disparities.

        ``cameras`` (port and position) and ``optics`` make it an `elphel tp capture
        --geometry` file; ``window`` is the sensor window (``WOI_*``) whose pixels are
        ``image_size`` (the default window when absent).
        """
        return quad_geometry(quad_scene(board))

    @router.get("/quad/truth")
    def quad_truth() -> dict[str, Any]:
        """True disparity of every tile centre (8tx+4, 8ty+4) of the default window.

        Also each tile's region (``label`` into ``names``), whether its footprint stays
        inside that region (``interior``) and whether the region is textured; rows are
        tiles-Y.
        """
        scene = quad_scene(board)
        with lock:
            if not truths:
                truths.append(tile_truth(scene))
        return tile_truth_document(truths[0])

    @router.get("/quad/reference.ply")
    def quad_reference(step_px: float = 1.0, carriage_mm: float | None = None) -> Response:
        """The true surface seen by the quad's virtual centre camera (binary PLY, mm).

        One point every ``step_px`` of the centre view, for the carriage at ``carriage_mm``
        (default: where it is now; a quad not on the stage does not move).
        """
        if not 0.25 <= step_px <= 64:
            raise HTTPException(status_code=422, detail=f"step_px={step_px}; allowed: 0.25..64")
        offset = quad_offset_mm(board, carriage_mm)
        cloud = surface_cloud(quad_scene(board), step_px=step_px, carriage_mm=offset)
        return Response(ply_bytes(cloud), media_type="application/octet-stream")

    @router.get("/quad/depth/{camera}")
    def quad_depth(camera: int, carriage_mm: float | None = None) -> Response:
        """Camera ``camera``'s true depth per pixel (float32 TIFF, mm; inf where nothing)."""
        if not 0 <= camera <= 3:
            raise HTTPException(status_code=422, detail=f"camera={camera}; allowed: 0..3")
        offset = quad_offset_mm(board, carriage_mm)
        depth = depth_map(quad_scene(board), camera, carriage_mm=offset)
        buf = io.BytesIO()
        tifffile.imwrite(buf, depth, metadata={"unit": "mm", "camera": camera})
        return Response(buf.getvalue(), media_type="image/tiff")

    return router


def bind_loopback(port: int, host: str = "127.0.0.1") -> socket.socket:
    """A listening TCP socket on loopback; port 0 picks a free one."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as e:
        sock.close()
        raise OSError(e.errno, f"cannot listen on {host}:{port}: {e.strerror}") from e
    sock.listen(128)
    sock.setblocking(False)
    return sock


@dataclass
class Served:
    app: FastAPI
    sock: socket.socket

    @property
    def url(self) -> str:
        host, port = self.sock.getsockname()[:2]
        return f"http://{host}:{port}"


async def serve_all(
    served: list[Served],
    *,
    on_ready: Callable[[], None] = lambda: None,
    on_shutdown: Sequence[Callable[[], None]] = (),
) -> None:
    """Run every app on its socket until SIGINT or SIGTERM.

    ``on_ready`` runs once the signals are handled (the announcement: whoever reads it may
    stop the rig at once, and a SIGTERM must then stop it cleanly, not kill it).
    Each server has the daemon's request/idle timeouts; on a signal ``on_shutdown`` runs
    first (ending the event streams), so the rig stops within about a second.
    """
    servers = [
        GracefulServer(
            server_config(s.app, log_level="warning", access_log=False),
            on_shutdown=on_shutdown,
            handle_signals=False,
        )
        for s in served
    ]
    loop = asyncio.get_running_loop()

    def stop() -> None:
        for server in servers:
            server.should_exit = True

    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop)
    on_ready()
    await asyncio.gather(
        *(srv.serve(sockets=[s.sock]) for srv, s in zip(servers, served, strict=True))
    )


def serve_cameras(
    board: SimCameraBoard, camera: CameraService, *, firmware: str, port: int, public_reads: bool
) -> tuple[list[Served], str, str | None]:
    """The camera's servers on loopback, its URL and its token (None: the stock firmware).

    ``firmware`` "elphel" serves a stock NC393 (parsedit.php and imgsrv, no token);
    otherwise elphel-camd's REST API, whose reads need the token unless ``public_reads``
    and whose Host must be an address or localhost.
    """
    if firmware == "elphel":
        stock = StockFirmware(board, camera)
        cameras = [Served(parsedit_app(stock), bind_loopback(port))]
        imgsrv = consecutive_sockets(bind_loopback)
        cameras += [Served(imgsrv_app(stock, p), sock) for p, sock in enumerate(imgsrv)]
        host, http_port = cameras[0].sock.getsockname()[:2]
        return cameras, f"nc393://{host}:{http_port}?imgsrv={imgsrv[0].getsockname()[1]}", None
    token = new_token()
    app = create_app(camera, token=token, public_reads=public_reads, allowed_hosts=[])
    cameras = [Served(app, bind_loopback(port))]
    return cameras, cameras[0].url, token


def print_announcement(announce: dict[str, Any], *, scenario: str, seed: int) -> None:
    """What `elphel-sim up` serves, for a person, with a first command to try."""
    print(f"simulated rig up (scenario {scenario}, seed {seed}); Ctrl-C stops it", flush=True)
    for key, value in announce.items():
        if value is None:
            continue  # not served (no token, no pty) or not in effect (a uniform lens blur)
        print(f"  {key:17s} {value}", flush=True)
    hint = f"elphel camera info --camera {announce['camera_url']}"
    if announce["token"] is not None:
        hint += f" --token {announce['token']}"
    print(f"  try: {hint}", flush=True)


def serve_daemons(
    board: SimCameraBoard, *, firmware: str, port: int, public_reads: bool
) -> tuple[list[CameraService], list[Served], list[str], list[str | None]]:
    """The board's daemons: one for the board, or one per camera (``daemon_per_port``).

    Returns the camera services, their servers, their URLs and their tokens; ``port``
    is the first daemon's TCP port (the others take free ones).
    """
    if not board.daemon_per_port:
        camera = CameraService(board)
        one, url, token = serve_cameras(
            board, camera, firmware=firmware, port=port, public_reads=public_reads
        )
        return [camera], one, [url], [token]
    if firmware != "camd":
        raise ValueError(
            f"firmware={firmware!r}: this scenario's cameras are each served by elphel-camd "
            "(allowed: camd)"
        )
    cameras: list[CameraService] = []
    served: list[Served] = []
    urls: list[str] = []
    tokens: list[str | None] = []
    for n, camera_port in enumerate(sorted(board.fpga)):
        camera = CameraService(PortView(board, camera_port))
        servers, url, token = serve_cameras(
            board, camera, firmware=firmware, port=port if n == 0 else 0, public_reads=public_reads
        )
        cameras.append(camera)
        served += servers
        urls.append(url)
        tokens.append(token)
    return cameras, served, urls, tokens


def serve_leptons(
    ports: list[VoSPIPort], *, public_reads: bool
) -> tuple[list[CameraService], list[Served], list[str], list[str]]:
    """A lepton-board daemon per Lepton port, reading the port's frames as VoSPI bytes.

    Each serves elphel-camd's lepton board on the port's simulated VoSPI stream
    (`elphel_sim.lepton_vospi.vospi_board`), with a token of its own; the Lepton's CCI
    stays on the board's daemon. Returns the services, their servers, URLs and tokens.
    """
    cameras: list[CameraService] = []
    served: list[Served] = []
    urls: list[str] = []
    tokens: list[str] = []
    try:
        for port in ports:
            cameras.append(CameraService(port.board))
            tokens.append(new_token())
            app = create_app(
                cameras[-1], token=tokens[-1], public_reads=public_reads, allowed_hosts=[]
            )
            served.append(Served(app, bind_loopback(0)))
            urls.append(served[-1].url)
    except BaseException:
        for port in ports:
            port.board.close()
        raise
    return cameras, served, urls, tokens


def up(
    *,
    scenario: str,
    seed: int,
    camera_port: int,
    stage_port: int,
    as_json: bool,
    firmware: str = "camd",
    public_reads: bool = False,
    lens_blur: LensBlur | None = None,
) -> int:
    """Serve the rig; ``firmware`` "camd" (elphel-camd's REST) or "elphel" (stock NC393).

    ``public_reads``: elphel-camd answers reads without the token (its ``--public-reads``).
    ``lens_blur``: a lens blur on the cameras' images (None: a perfectly sharp lens).
    A scenario with a daemon per camera (pi-pair) also announces ``camera_urls`` and
    ``tokens``, camera i being port i of the inspection endpoint. A scenario with Lepton
    ports (mixed) also announces ``lepton_urls`` and ``lepton_tokens``: a lepton-board
    daemon per Lepton port, reading that port's frames through the VoSPI reader.
    """
    # Frames are formed in child processes: in this one, forming would hold the interpreter
    # lock that the daemon's answers need (a capture unanswered for 30 s on a busy machine).
    board = SimCameraBoard(
        build(scenario, seed=seed, lens_blur=lens_blur), seed=seed, forming="process"
    )
    try:
        cameras, served, urls, tokens = serve_daemons(
            board, firmware=firmware, port=camera_port, public_reads=public_reads
        )
    except OSError:  # the camera port is taken
        board.close()
        raise
    board.start_clock()
    try:
        stage = SimStage(board.world, seed=seed, tcp_port=stage_port).start()
    except OSError:
        close_daemons(cameras, board, served)
        raise
    sim_served = Served(create_sim_app(board, stage), bind_loopback(0))
    vospi = [vospi_board(board, port, seed=seed) for port in lepton_ports(board)]
    leptons, lepton_served, lepton_urls, lepton_tokens = serve_leptons(
        vospi, public_reads=public_reads
    )
    sim_served.app.include_router(vospi_fault_router(vospi))
    announce: dict[str, Any] = {"camera_url": urls[0], "token": tokens[0]}
    if board.daemon_per_port:
        announce.update(camera_urls=urls, tokens=tokens)
    if leptons:
        announce.update(lepton_urls=lepton_urls, lepton_tokens=lepton_tokens)
    announce.update(
        stage_url=stage.tcp_url,
        stage_pty=stage.pty_path,
        sim_url=sim_served.url,
        **(lens_blur or SHARP).to_json(),
    )

    def announce_rig() -> None:
        if as_json:
            print(json.dumps(announce), flush=True)
        else:
            print_announcement(announce, scenario=scenario, seed=seed)

    try:
        closing = [camera.events.close for camera in (*cameras, *leptons)]
        asyncio.run(
            serve_all(
                [*served, sim_served, *lepton_served], on_ready=announce_rig, on_shutdown=closing
            )
        )
    finally:
        stage.close()
        # the VoSPI readers before the board they read
        close_daemons((*leptons, *cameras), board, (*served, sim_served, *lepton_served))
    print("elphel-sim: stopped", file=sys.stderr)
    return 0


def close_daemons(
    cameras: Sequence[CameraService], board: SimCameraBoard, served: Sequence[Served]
) -> None:
    """Close the daemons' services (a single daemon closes its board too), then their sockets."""
    for camera in cameras:
        camera.close()
    if board.daemon_per_port:
        board.close()
    for s in served:
        s.sock.close()
