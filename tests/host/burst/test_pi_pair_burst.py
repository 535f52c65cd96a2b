"""The dissertation's rig (pi-pair): a x2 burst from each IMX219, fused, against the truth.

Two IMX219 cameras 89.98 mm apart on the carriage, each served by its own daemon (a
`PortView` of the shared simulated board, as `elphel-sim up --scenario pi-pair` serves
them). At every position of the x2 Bayer plan both cameras take their next frame; each
camera's burst is fused by MFSR and scored, as `elphel mfsr compare` scores, against the
scene seen by pixels of half the pitch from that camera's pose at the first frame.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from elphel_camd.sensors import imx219_registers as regs
from elphel_camd.service import CameraService
from elphel_host.burst.plan import plan_burst
from elphel_host.mfsr.fuse import fuse_frames
from elphel_host.mfsr.metrics import psnr
from elphel_sim.board import SimCameraBoard
from elphel_sim.port_view import PortView
from elphel_sim.render import Intrinsics, render_radiance
from elphel_sim.scenarios import (
    PI_PAIR_DISTANCE_MM,
    PI_PAIR_FOCAL_LENGTH_MM,
    build,
)

SEED = 7
SCALE = 2
FRAMES = 16
WINDOW = {"WOI_LEFT": 1560, "WOI_TOP": 1172, "WOI_WIDTH": 160, "WOI_HEIGHT": 120}
START_MM = 20.0


def reference(board: SimCameraBoard, port: int, carriage_mm: float, meta: dict[str, Any]):
    """The camera's view at ``carriage_mm`` with SCALE x finer pixels, in its DN."""
    spec = board.ports[port]
    lr = spec.intrinsics
    cx, cy = lr.principal_point
    hr = Intrinsics(
        lr.focal_length_mm,
        lr.pixel_pitch_um / SCALE,
        lr.width * SCALE,
        lr.height * SCALE,
        cx * SCALE,
        cy * SCALE,
    )
    left = (regs.ACTIVE_LEFT + meta["WOI_LEFT"]) * SCALE
    top = (regs.ACTIVE_TOP + meta["WOI_TOP"]) * SCALE
    window = (left, top, meta["WOI_WIDTH"] * SCALE, meta["WOI_HEIGHT"] * SCALE)
    world = board.world
    before, world.rig.carriage_mm = world.rig.carriage_mm, carriage_mm
    try:
        rgb = render_radiance(world, hr, world.camera_pose(spec.mount), window=window)
    finally:
        world.rig.carriage_mm = before
    model = spec.sensor
    dn = rgb * meta["EXPOS"] * model.electrons_per_us * model.dn_per_e
    return np.clip(dn, 0, (1 << model.bits) - 1).astype(np.float32)


@pytest.fixture(scope="module")
def bursts() -> list[tuple[list[NDArray[np.uint16]], dict[str, Any], np.ndarray]]:
    board = SimCameraBoard(build("pi-pair", seed=SEED), seed=SEED, noise=True)
    cameras = [CameraService(PortView(board, port)) for port in (0, 1)]
    for camera in cameras:
        target = camera.set_params(0, WINDOW)
        camera.capture(0, frame=target)
    plan = plan_burst(
        scale=SCALE,
        focal_length_mm=PI_PAIR_FOCAL_LENGTH_MM,
        pixel_pitch_um=regs.PIXEL_PITCH_UM,
        distance_mm=PI_PAIR_DISTANCE_MM,
        frames=FRAMES,
        bayer=True,
    )
    taken: list[list[tuple[Any, dict[str, Any]]]] = [[], []]
    for rel_mm in plan.positions_mm:
        board.world.rig.carriage_mm = START_MM + rel_mm
        for c, camera in enumerate(cameras):  # the next frame of each starts after the move
            taken[c].append(camera.capture(0))
    out = []
    for port, frames in enumerate(taken):
        first, meta = frames[0]
        truth = board.sim_frame_truth(port, first.frame)
        ref = reference(board, port, float(truth["carriage_mm"]), meta)
        out.append(([f.image for f, _ in frames], meta, ref))
    board.close()
    return out


def _psnr(image: np.ndarray, ref: np.ndarray) -> float:
    span = float(ref.max() - ref.min())
    return psnr(ref.mean(axis=2), image.mean(axis=2), data_range=span, border=4 * SCALE)


def test_each_camera_bursts_raw10_rggb_on_the_reference_grid(bursts):
    for frames, meta, ref in bursts:
        assert meta["sensor"] == "IMX219" and meta["bayer"] == "RGGB" and len(frames) == FRAMES
        assert max(int(f.max()) for f in frames) <= 1023
        assert ref.shape == (SCALE * 120, SCALE * 160, 3)


@pytest.mark.parametrize("camera", [0, 1])
def test_robust_fusion_beats_bicubic_by_2_db_against_the_truth(bursts, camera):
    frames, meta, ref = bursts[camera]
    bic = fuse_frames(frames, scale=SCALE, method="bicubic", bayer=meta["bayer"])
    rob = fuse_frames(frames, scale=SCALE, method="robust", bayer=meta["bayer"])
    assert rob.excluded == []
    p_bic, p_rob = _psnr(bic.image, ref), _psnr(rob.image, ref)
    # measured (seed 7): bicubic 32.5 / 33.5 dB, robust 45.7 / 47.7 dB (cameras 0 / 1)
    assert p_rob >= p_bic + 2.0, (p_bic, p_rob)
