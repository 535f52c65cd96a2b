"""The Micro-Manager devices (elphel_host.mm) in pymmcore-plus's UniMMCore, on a simulated rig."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
import useq
from pymmcore_plus.experimental.unicore import UniMMCore

from elphel_host.camera.client import CameraClient, CameraHTTPError
from elphel_host.errors import CameraAuthError
from elphel_host.mm import CAMERA_LABEL, STAGE_LABEL, load_elphel_devices

pytestmark = pytest.mark.slow
TOLERANCE_UM = 10.0


@pytest.fixture
def core(tmp_path: Path) -> Iterator[UniMMCore]:
    # No C++ adapters are needed: an empty search path keeps pymmcore-plus from looking
    # for a Micro-Manager installation.
    mmc = UniMMCore(mm_path=str(tmp_path))
    try:
        yield mmc
    finally:
        mmc.unloadAllDevices()


def true_um(sim_url: str) -> float:
    """Where the carriage really is, in the caliper's frame (µm)."""
    truth = httpx.get(f"{sim_url}/stage", timeout=10).json()
    return 1000.0 * (truth["true_mm"] - truth.get("caliper_zero_mm", 0.0))


def test_stage_moves_closed_loop_and_zeroes(elphel_rig, core):
    labels = load_elphel_devices(core, stage_url=elphel_rig.stage_url)
    assert labels == [STAGE_LABEL]
    assert core.getFocusDevice() == STAGE_LABEL
    for target in (30_000.0, 12_345.0):
        core.setPosition(target)
        assert core.deviceBusy(STAGE_LABEL)  # the move runs; setPosition returned at once
        core.waitForDevice(STAGE_LABEL)
        assert abs(true_um(elphel_rig.sim_url) - target) <= TOLERANCE_UM
        assert abs(core.getPosition() - target) <= TOLERANCE_UM

    core.setOrigin(STAGE_LABEL)
    assert abs(core.getPosition()) <= TOLERANCE_UM
    assert abs(true_um(elphel_rig.sim_url)) <= TOLERANCE_UM  # the caliper was zeroed here
    core.setPosition(5_000.0)
    core.waitForDevice(STAGE_LABEL)
    assert abs(true_um(elphel_rig.sim_url) - 5_000.0) <= TOLERANCE_UM


def test_stage_stop_ends_a_move(elphel_rig, core):
    load_elphel_devices(core, stage_url=elphel_rig.stage_url)
    start = true_um(elphel_rig.sim_url)
    core.setPosition(start + 60_000.0)
    time.sleep(1.0)
    t0 = time.monotonic()
    core.stop(STAGE_LABEL)
    core.waitForDevice(STAGE_LABEL)
    assert time.monotonic() - t0 < 5.0
    assert not core.deviceBusy(STAGE_LABEL)
    where = true_um(elphel_rig.sim_url)
    time.sleep(0.5)
    assert true_um(elphel_rig.sim_url) == pytest.approx(where, abs=1.0)  # it stays stopped
    assert where < start + 50_000.0
    assert abs(core.getPosition() - where) <= TOLERANCE_UM


def test_camera_snap_sequence_and_limits(elphel_rig, core):
    load_elphel_devices(core, camera_url=elphel_rig.camera_url, token=elphel_rig.token)
    assert core.getCameraDevice() == CAMERA_LABEL
    assert core.getProperty(CAMERA_LABEL, "Sensor") == "MT9P006"
    assert core.getImageBitDepth() == 16
    assert core.getAllowedPropertyValues(CAMERA_LABEL, "Binning") == ("1",)

    core.setROI(1000, 700, 320, 240)
    assert core.getROI() == [1000, 700, 320, 240]
    core.setExposure(5.0)
    assert core.getExposure() == pytest.approx(5.0, abs=0.05)  # whole rows
    core.snapImage()
    image = core.getImage()
    assert image.shape == (240, 320) and image.dtype == np.uint16 and image.std() > 0

    # A sequence's frames are the daemon's frames, pixel for pixel (40 ms frames keep
    # them in the daemon's 64-frame ring buffer long enough to fetch them again).
    core.setExposure(40.0)
    core.startSequenceAcquisition(3, 0, True)
    while core.isSequenceRunning():
        time.sleep(0.05)
    images = []
    while core.getRemainingImageCount():
        img, meta = core.popNextImageAndMD()
        images.append((img, int(meta["Elphel-frame"])))
    assert len(images) == 3
    frames = [f for _, f in images]
    assert frames == list(range(frames[0], frames[0] + 3))
    with CameraClient(elphel_rig.camera_url, elphel_rig.token) as cam:
        kept = cam.capture(frame=frames[-1])
        np.testing.assert_array_equal(images[-1][0], kept.image)

        # The property limits are the daemon's ranges, which depend on the window (row
        # time): one µs beyond the upper limit is refused with exactly that range.
        highs = []
        for roi in ((0, 0, 2592, 1944), (1000, 700, 320, 240)):
            core.setROI(*roi)
            low = core.getPropertyLowerLimit(CAMERA_LABEL, "Exposure")
            high_us = round(core.getPropertyUpperLimit(CAMERA_LABEL, "Exposure") * 1000)
            assert round(low * 1000) == 1
            with pytest.raises(CameraHTTPError) as refused:
                cam.set_params({"EXPOS": high_us + 1})
            assert refused.value.status == 409  # allowed by the schema, refused by the sensor
            assert refused.value.allowed == f"{round(low * 1000)}..{high_us}"
            highs.append(high_us)
        assert highs[0] != highs[1]

    # An odd window is refused with the reason, not rounded.
    with pytest.raises(Exception, match="even"):
        core.setROI(1001, 700, 320, 240)


def test_exposure_upper_limit_is_taken(elphel_rig, core):
    load_elphel_devices(core, camera_url=elphel_rig.camera_url, token=elphel_rig.token)
    core.setROI(1000, 700, 320, 240)
    high = core.getPropertyUpperLimit(CAMERA_LABEL, "Exposure")
    core.setExposure(high)
    assert core.getExposure() == pytest.approx(high, abs=0.1)


def test_mda_over_stage_positions(elphel_rig, core):
    load_elphel_devices(
        core,
        camera_url=elphel_rig.camera_url,
        token=elphel_rig.token,
        stage_url=elphel_rig.stage_url,
    )
    core.setROI(1000, 700, 320, 240)
    targets = [20_000.0, 25_000.0, 30_000.0, 35_000.0, 40_000.0]
    sequence = useq.MDASequence(
        stage_positions=[useq.Position(z=z) for z in targets],
        time_plan={"interval": 0, "loops": 2},
        axis_order="ptgcz",
    )
    frames = []

    def on_frame(image: np.ndarray, event: useq.MDAEvent, meta: dict) -> None:
        truth = true_um(elphel_rig.sim_url)
        frames.append((image.shape, dict(event.index), event.z_pos, meta, truth))

    core.mda.events.frameReady.connect(on_frame)
    core.mda.run(sequence)
    assert len(frames) == 10
    seen = [(index["p"], index["t"]) for _, index, *_ in frames]
    assert seen == [(p, t) for p in range(5) for t in range(2)]
    for shape, index, z, meta, truth in frames:
        assert shape == (240, 320)
        assert z == targets[index["p"]]
        assert abs(meta["position"]["z"] - z) <= TOLERANCE_UM
        assert abs(truth - z) <= TOLERANCE_UM


def test_a_wrong_token_fails_at_load_time(elphel_rig, core):
    with pytest.raises(CameraAuthError, match=r"wrong token: the camera at .* refused it"):
        load_elphel_devices(core, camera_url=elphel_rig.camera_url, token="wrong")
    assert CAMERA_LABEL not in core.getLoadedDevices()
    with pytest.raises(CameraAuthError, match="needs its token"):
        load_elphel_devices(core, camera_url=elphel_rig.camera_url, token=None)
