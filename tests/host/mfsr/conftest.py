from __future__ import annotations

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray

from elphel_host.mfsr.synth import make_burst, random_shifts


def scene(size: int = 256) -> NDArray[np.float32]:
    """A seeded band-rich test image (edges, texture, smooth areas) in [0, 1]."""
    rng = np.random.default_rng(7)
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    img = 0.5 + 0.25 * np.sin(xx * 0.21 + yy * 0.05) * np.cos(yy * 0.13)
    img += (((xx // 24 + yy // 24) % 2) * 0.2 - 0.1).astype(np.float32)
    noise = cv2.GaussianBlur(rng.normal(0, 1, (size, size)).astype(np.float32), (0, 0), 1.2)
    img += 0.15 * noise
    cv2.circle(img, (size // 2, size // 2), size // 5, 0.9, 2)
    return np.clip(img, 0, 1).astype(np.float32)


@pytest.fixture(scope="session")
def hr() -> NDArray[np.float32]:
    return scene()


@pytest.fixture(scope="session")
def burst2(hr: NDArray[np.float32]) -> tuple[list[NDArray[np.float32]], NDArray[np.float64]]:
    shifts = random_shifts(16, seed=3, spread=2.0)
    return make_burst(hr, shifts, scale=2, noise_sigma=0.01, seed=4), shifts
