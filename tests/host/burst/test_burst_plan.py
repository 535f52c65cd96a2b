from __future__ import annotations

import math

import numpy as np
import pytest

from elphel_host.burst.plan import plan_burst


def test_tilted_plan_visits_every_phase():
    p = plan_burst(scale=2, focal_length_mm=35, pixel_pitch_um=2.2, distance_mm=500)
    assert p.frames == 4 and p.positions_mm[0] == 0
    assert math.tan(math.radians(p.tilt_deg)) == pytest.approx(0.5)
    ph = np.asarray(p.phases)
    # x phases on the 1/S lattice, y phases all distinct: S^2 distinct 2-D phases
    assert sorted({round(v * 2) % 2 for v in ph[:, 1]}) == [0, 1]
    assert len({(round(a, 3), round(b, 3)) for a, b in ph}) == 4
    shifts = np.asarray(p.shifts_px)
    assert np.allclose(np.diff(shifts[:, 1]), 0.5, atol=1e-4)
    # object plane shift per mm: f / (Z - f) / pitch
    assert p.px_per_mm == pytest.approx(35 / 465 * 1000 / 2.2)
    assert any("one linear axis" in n for n in p.notes)
    assert any("parallax" in n for n in p.notes)


def test_steps_rounding_and_warning():
    p = plan_burst(
        scale=4,
        focal_length_mm=35,
        pixel_pitch_um=2.2,
        distance_mm=500,
        mm_per_step=0.008778,
        frames=16,
    )
    assert p.steps is not None and p.steps[0] == 0
    assert p.positions_mm == pytest.approx([s * 0.008778 for s in p.steps])
    assert any("coarse" in n for n in p.notes)


@pytest.mark.parametrize(
    ("kw", "needle"),
    [
        ({"scale": 1}, "scale=1; allowed"),
        ({"distance_mm": 20}, "distance_mm=20; allowed: > focal_length_mm"),
        ({"pixel_pitch_um": 0}, "pixel_pitch_um=0; allowed"),
        ({"frames": 1}, "frames=1; allowed"),
    ],
)
def test_plan_rejects(kw, needle):
    args = {"scale": 2, "focal_length_mm": 35, "pixel_pitch_um": 2.2, "distance_mm": 500}
    args.update(kw)
    with pytest.raises(ValueError, match=needle):
        plan_burst(**args)


def test_bayer_plan_visits_every_phase_of_the_2px_period():
    p = plan_burst(scale=2, focal_length_mm=35, pixel_pitch_um=2.2, distance_mm=500, bayer=True)
    assert p.bayer and p.period_px == 2 and p.frames == 16
    assert math.tan(math.radians(p.tilt_deg)) == pytest.approx(0.25)
    shifts = np.asarray(p.shifts_px)
    assert np.allclose(np.diff(shifts[:, 1]), 0.5, atol=1e-4)  # 1/S px along x
    ph = np.asarray(p.phases)
    assert ph.max() < 2 and sorted({round(v * 2) for v in ph[:, 1]}) == [0, 1, 2, 3]
    assert len({(round(a, 3), round(b, 3)) for a, b in ph}) == 16
    assert any("Bayer" in n for n in p.notes)
    mono = plan_burst(scale=2, focal_length_mm=35, pixel_pitch_um=2.2, distance_mm=500)
    assert not mono.bayer and any("--bayer" in n for n in mono.notes)
