"""`tile_pass.stage_times`: where a pass spends its time, without changing what it computes."""

from __future__ import annotations

import tempfile

import numpy as np

from elphel_host.tp import io, processor, tile_pass
from elphel_host.tp.config import TpConfig
from elphel_sim import quad as simquad


def test_stage_times_cover_every_stage_and_leave_results_alone() -> None:
    rig = simquad.QuadRig(width=128, height=96)
    scene = simquad.standard_scene(rig, seed=3)
    raw = simquad.render_quad(scene, seed=3)
    with tempfile.TemporaryDirectory() as tmp:
        simquad.write_quad_dir(tmp, raw, rig)
        quad = io.read_quad_dir(tmp).quad
    config = TpConfig(threads=2, chunk_tiles=64)
    plain = processor.disparity_map(quad, config=config)
    with tile_pass.stage_times() as outer:
        with tile_pass.stage_times() as inner:
            timed = processor.disparity_map(quad, config=config)
        after_inner = dict(inner)
        processor.disparity_map(quad, config=config)
    assert set(outer) == set(tile_pass.STAGES)
    assert all(v > 0 for v in after_inner.values()), after_inner
    # the outer collector saw both runs, the inner one only the first
    assert all(outer[k] > after_inner[k] for k in tile_pass.STAGES)
    assert dict(inner) == after_inner
    for k in plain:
        assert np.array_equal(plain[k], timed[k], equal_nan=True), k
    # nothing is collected outside the block
    before = dict(outer)
    processor.disparity_map(quad, config=config)
    assert dict(outer) == before
