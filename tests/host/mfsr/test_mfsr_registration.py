from __future__ import annotations

import numpy as np

from elphel_host.mfsr.registration import register_frames
from elphel_host.mfsr.robust import reconstruct


def _rms(est: list[tuple[float, float]], truth: np.ndarray) -> float:
    e = np.asarray(est) - truth
    return float(np.sqrt(np.mean(np.sum(e[1:] ** 2, axis=1))))


def test_known_shifts_recovered(burst2):
    frames, shifts = burst2
    regs = register_frames(frames)
    assert all(r.ok for r in regs)
    assert _rms([r.shift for r in regs], shifts) < 0.06  # LR px, ECC at LR (aliasing bias)


def test_model_refinement_reaches_003_px(burst2):
    frames, shifts = burst2
    regs = register_frames(frames)
    _, info = reconstruct(frames, [r.shift for r in regs], scale=2)
    assert _rms(info["shifts_refined"], shifts) <= 0.03


def test_large_integer_shift_and_prior(burst2, hr):
    from elphel_host.mfsr.synth import make_burst

    truth = np.array([[0.0, 0.0], [3.4, -7.3]])
    frames = make_burst(hr, truth, scale=2, noise_sigma=0.01, seed=1)
    regs = register_frames(frames, prior=[(0.0, 0.0), (3.0, -7.0)])
    assert regs[1].ok
    assert np.hypot(*(np.asarray(regs[1].shift) - truth[1])) < 0.08


def test_unrelated_frame_is_rejected_and_reported(burst2):
    frames, _ = burst2
    rng = np.random.default_rng(0)
    bad = rng.uniform(0, 1, frames[0].shape).astype(np.float32)
    regs = register_frames([*frames[:3], bad])
    assert [r.ok for r in regs] == [True, True, True, False]
    assert regs[3].shift is None and regs[3].reason
