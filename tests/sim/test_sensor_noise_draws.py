"""The read-out's fast paths: table-lookup normal draws, the kept colour-filtered radiance."""

from __future__ import annotations

import numpy as np

from elphel_sim.render.sensor import Readout, SensorModel, _filtered, read_out, standard_normal


def test_table_normal_draws_are_standard_normal() -> None:
    draws = standard_normal(np.random.default_rng(3), (2000, 1000))
    assert draws.dtype == np.float32 and draws.shape == (2000, 1000)
    z = draws.astype(np.float64)
    assert abs(z.mean()) < 0.003 and abs(z.std() - 1.0) < 0.003
    assert abs(np.mean(z**3)) < 0.01 and abs(np.mean(z**4) - 3.0) < 0.03  # skew, kurtosis
    assert 4.2 < np.abs(z).max() <= 4.33  # the table's tails
    assert abs(np.mean(np.abs(z) > 2.0) - 0.0455) < 0.001
    same = standard_normal(np.random.default_rng(3), (2000, 1000))
    np.testing.assert_array_equal(same, z.astype(np.float32))  # seeded: the same draws


def _readout(**kw: object) -> Readout:
    base = dict(
        left=0,
        top=0,
        width=64,
        height=48,
        exposure_us=10_000.0,
        gains=(1.0, 1.0, 1.0, 1.5),
        fliph=False,
        flipv=False,
        bayer="GRBG",
    )
    return Readout(**{**base, **kw})  # type: ignore[arg-type]


def test_kept_filtered_radiance_gives_the_same_frames() -> None:
    rng = np.random.default_rng(1)
    radiance = rng.uniform(0.2, 0.8, (1, 48, 64, 3))
    kept = radiance.copy()
    kept.flags.writeable = False  # as `render_strips` keeps a still scene's radiance
    model = SensorModel()
    for readout in (_readout(), _readout(left=1), _readout(gains=(2.0, 1.0, 1.0, 1.0))):
        want = read_out(radiance, readout, model=model, rng=np.random.default_rng(7))
        for _ in range(2):  # formed, then from what was kept
            got = read_out(kept, readout, model=model, rng=np.random.default_rng(7))
            np.testing.assert_array_equal(got, want)
    assert kept.flags.writeable is False and np.array_equal(kept, radiance)


def test_filtered_radiance_is_kept_for_views_and_apart_from_the_gains() -> None:
    # `render_strips` hands out a new read-only view of the kept radiance each time.
    kept = np.random.default_rng(2).uniform(0.2, 0.8, (1, 48, 64, 3))
    kept.flags.writeable = False
    first, gain = _filtered(kept.view(), _readout())
    again, _ = _filtered(kept.view(), _readout())
    assert again is first  # the same view of the same array: not filtered again
    other_gain, other = _filtered(kept.view(), _readout(gains=(2.0, 1.0, 1.0, 1.0)))[::-1]
    assert other is first and not np.array_equal(other_gain, gain)  # a gain is not a filter
    assert _filtered(kept.view(), _readout(left=1))[0] is not first  # another Bayer phase
    assert _filtered(kept[:, 1:].view(), _readout())[0] is not first  # another part of it
    writeable = kept.copy()
    assert _filtered(writeable, _readout())[0] is not _filtered(writeable, _readout())[0]
    # a read-only view of an array that can still change is not kept either
    ro = writeable.view()
    ro.flags.writeable = False
    assert _filtered(ro, _readout())[0] is not _filtered(ro, _readout())[0]
