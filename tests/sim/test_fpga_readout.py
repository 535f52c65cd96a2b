"""The seams between the FPGA model and the renderer: settings by frame, and the readout."""

from __future__ import annotations

import numpy as np
import pytest

from elphel_camd.params import TRIGGERMODE, TRIGSEQ, WINDOW
from elphel_sim.chips.sensor import SensorTiming
from elphel_sim.fpga import Camsync, PortFPGA, PortSettings
from elphel_sim.render import Intrinsics, Readout, SensorModel, expose, mosaic, read_out

TIMING = SensorTiming(row_s=1e-5, frame_rows=1000, exposure_rows=100, height=900)


def trigseq(frame: int, master: int) -> dict[str, int]:
    return {
        "FRAME": frame,
        "TRIG_DELAY": 7,
        "TRIG_DECIMATE": 1,
        "TRIG_MASTER": master,
        "TRIG_PERIOD": 100_000,
    }


def test_settings_wait_for_their_frame_and_the_master_programs_the_trigger() -> None:
    fpga = PortFPGA()
    fpga.program(0, TRIGSEQ, trigseq(3, master=0))
    fpga.program(0, TRIGGERMODE, {"FRAME": 3, "TRIG": 4})
    fpga.program(0, WINDOW, {"FRAME": 4, "PF_HEIGHT": 8, "WOI_HEIGHT": 64})
    fpga.frame = 2
    assert fpga.apply_due() == []
    assert fpga.settings == PortSettings()
    fpga.frame = 3
    assert fpga.apply_due() == [100_000]
    assert fpga.settings == PortSettings(snapshot=True, delay_10ns=7, decimate=1)
    fpga.frame = 4
    assert fpga.apply_due() == []
    assert fpga.settings.pf_strips == 8
    assert fpga.pending == []


def test_only_the_master_port_programs_the_common_trigger() -> None:
    fpga = PortFPGA()
    fpga.program(1, TRIGSEQ, trigseq(0, master=0))
    assert fpga.apply_due() == []
    assert fpga.settings.decimate == 1


def test_free_run_frames_follow_the_frame_period_and_snapshot_waits_for_triggers() -> None:
    fpga = PortFPGA()
    camsync = Camsync()
    fpga.schedule_next(TIMING, sensor_snapshot=False, camsync=camsync, now_s=0.0)
    assert fpga.next_start_s == 0.0
    assert fpga.start_frame() == 0.0
    fpga.schedule_next(TIMING, sensor_snapshot=False, camsync=camsync, now_s=0.0)
    assert fpga.next_start_s == pytest.approx(TIMING.frame_s)
    fpga.settings = PortSettings(snapshot=True)
    fpga.schedule_next(TIMING, sensor_snapshot=True, camsync=camsync, now_s=0.0)
    assert fpga.next_start_s == float("inf")  # the trigger generator is stopped
    camsync.program(100_000, 0.5)  # 1 ms period from t = 0.5 s
    fpga.schedule_next(TIMING, sensor_snapshot=True, camsync=camsync, now_s=0.5)
    assert fpga.next_timestamp_s == pytest.approx(0.5)


def test_readout_window_is_clipped_to_the_array() -> None:
    intrinsics = Intrinsics(focal_length_mm=4.5, pixel_pitch_um=2.2, width=100, height=80)
    readout = Readout(90, 70, 32, 32, 1000.0, (1.0, 1.0, 1.0, 1.0), False, False, "GRBG")
    assert readout.window_on(intrinsics) == (90, 70, 10, 10)


def test_read_out_with_unit_gains_is_mosaic_then_expose() -> None:
    rng = np.random.default_rng(3)
    radiance = rng.uniform(0.0, 1.0, (1, 6, 8, 3))
    model = SensorModel(bits=12, electrons_per_us=0.8)
    readout = Readout(1, 2, 8, 6, 5000.0, (1.0, 1.0, 1.0, 1.0), False, False, "GRBG")
    image = read_out(radiance, readout, model=model, rng=None)
    raw = mosaic(radiance[0], "GRBG", row0=2, col0=1)
    np.testing.assert_array_equal(image, expose(raw, exposure_us=5000.0, model=model))


def test_read_out_gains_flips_and_strips() -> None:
    radiance = np.ones((2, 4, 4, 3))
    radiance[1] *= 0.5
    radiance[:, :, 0, :] = 0.0  # a dark first column
    model = SensorModel(bits=12, electrons_per_us=1.0, full_well_e=1e6, dn_per_e=1.0)
    gains = (2.0, 1.0, 1.5, 3.0)  # red, green on red rows, green on blue rows, blue
    readout = Readout(0, 0, 4, 4, 100.0, gains, True, False, "GRBG")
    image = read_out(radiance, readout, model=model, rng=None)
    assert image.shape == (8, 4)
    # GRBG: row 0 is G R G R (green on red rows), row 1 is B G B G (green on blue rows)
    np.testing.assert_array_equal(image[0], [200, 100, 200, 0])  # flipped: dark column last
    np.testing.assert_array_equal(image[1], [150, 300, 150, 0])
    np.testing.assert_array_equal(image[4], [100, 50, 100, 0])  # the second strip, half as bright
