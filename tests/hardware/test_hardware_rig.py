"""On real hardware: run only when ELPHEL_HW_CAMERA_URL / ELPHEL_HW_STAGE_URL name devices.

    ELPHEL_HW_CAMERA_URL=http://camera:8000 ELPHEL_HW_CAMERA_TOKEN=... \\
    ELPHEL_HW_STAGE_URL=/dev/ttyUSB0 .venv/bin/pytest tests/hardware
"""

import os

import numpy as np
import pytest

from elphel_host.camera.client import CameraClient
from elphel_host.stage.client import StageClient

CAMERA = os.environ.get("ELPHEL_HW_CAMERA_URL")
STAGE = os.environ.get("ELPHEL_HW_STAGE_URL")
KNOWN = {"MT9P006", "MT9F002", "LEPTON35"}


@pytest.mark.hardware
@pytest.mark.skipif(not CAMERA, reason="set ELPHEL_HW_CAMERA_URL to test a real camera")
def test_camera_reports_known_sensors_and_captures_16bit_frames():
    with CameraClient(CAMERA, os.environ.get("ELPHEL_HW_CAMERA_TOKEN")) as camera:
        info = camera.info()
        models = {p["sensor"]["model"] for p in info["ports"] if p["sensor"]}
        assert models and models <= KNOWN
        port = next(p["port"] for p in info["ports"] if p["sensor"])
        if "capture" in info.get("capabilities", ["capture"]):
            frame = camera.capture(port)
            assert frame.image.dtype == np.uint16
            assert frame.image.shape == (frame.metadata["WOI_HEIGHT"], frame.metadata["WOI_WIDTH"])


@pytest.mark.hardware
@pytest.mark.skipif(not STAGE, reason="set ELPHEL_HW_STAGE_URL to test a real stage")
def test_stage_identifies_and_reads_its_caliper():
    with StageClient(STAGE) as stage:
        ident = stage.identify()
        assert ident.firmware
        status = stage.status()
        assert status.state
        assert -1000.0 < stage.read_caliper_mm() < 1000.0
