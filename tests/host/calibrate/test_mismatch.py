"""`elphel_host.calibrate.mismatch`: the 2-D peak of a pair's CLT-domain correlation."""

from __future__ import annotations

import numpy as np

from elphel_host.calibrate.mismatch import continuous_peak
from elphel_host.tp.clt.transform import OMEGA


def shifted_products(shifts: np.ndarray) -> np.ndarray:
    """Weighted products ``(N, 8, 2, 8)`` whose correlation peaks exactly at ``shifts`` (N, 2)."""
    wh, wv = OMEGA[:, None], OMEGA[None, :]
    weight = np.exp(-(wh**2 + wv**2))  # any positive weights: every term is 1 at the shift
    out = np.empty((len(shifts), 8, 2, 8), dtype=np.complex128)
    for n, (sx, sy) in enumerate(shifts):
        out[n, :, 0, :] = weight * np.exp(1j * (wh * sx + wv * sy))
        out[n, :, 1, :] = weight * np.exp(1j * (wh * sx - wv * sy))
    return out


def test_the_peak_is_found_to_a_thousandth_of_a_pixel() -> None:
    shifts = np.array([[0.0, 0.0], [1.3, -0.7], [-2.45, 0.5], [0.2, 2.9]])
    pos, value = continuous_peak(shifted_products(shifts), 3)
    assert np.allclose(pos, shifts, atol=1e-3)
    assert np.allclose(value, value[0])
