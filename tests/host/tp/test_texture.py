"""Inverse-CLT renders and RGBA textures."""

from __future__ import annotations

import numpy as np
import pytest

from elphel_host.tp import texture
from elphel_host.tp.geometry import IDEAL_POSITIONS
from elphel_host.tp.images import QuadImages


def smooth_quad(disparity: float, *, bayer: str | None, size: int = 96) -> QuadImages:
    rng = np.random.default_rng(0)
    f = np.fft.fftfreq(size)
    fy, fx = f[:, None], f[None, :]
    spec = (rng.normal(size=(3, size, size)) + 1j * rng.normal(size=(3, size, size))) * (
        np.hypot(fx, fy) < 0.12
    )
    views = []
    for px, py in IDEAL_POSITIONS:
        rgb = np.fft.ifft2(spec * np.exp(2j * np.pi * disparity * (fx * px + fy * py))).real
        rgb = 0.5 + 0.1 * rgb / np.abs(rgb).max()
        if bayer is None:
            views.append(rgb.mean(0))
        else:
            m = np.empty((size, size))
            m[0::2, 0::2], m[0::2, 1::2] = rgb[1, 0::2, 0::2], rgb[0, 0::2, 1::2]
            m[1::2, 0::2], m[1::2, 1::2] = rgb[2, 1::2, 0::2], rgb[1, 1::2, 1::2]
            views.append(m)
    return QuadImages(np.asarray(views, dtype=np.float32), bayer=bayer)


def test_render_at_zero_disparity_reproduces_mono_image() -> None:
    q = smooth_quad(0.0, bayer=None)
    img = texture.rendered_images(q, 0.0)
    assert img.shape == (4, 1, 96, 96)
    assert np.abs(img[:, 0] - q.images)[:, 4:-4, 4:-4].max() < 1e-4


@pytest.mark.parametrize("bayer", [None, "GRBG"])
def test_cameras_agree_at_true_disparity_only(bayer: str | None) -> None:
    q = smooth_quad(2.3, bayer=bayer)
    inner = (slice(None), slice(None), slice(12, -12), slice(12, -12))
    right = texture.rendered_images(q, 2.3)[inner]
    wrong = texture.rendered_images(q, 0.0)[inner]
    spread_right = np.abs(right - right.mean(0)).max()
    spread_wrong = np.abs(wrong - wrong.mean(0)).max()
    assert spread_right < 0.004
    assert spread_wrong > 5 * spread_right
    rgba_right = texture.rgba_texture(
        texture.rendered_images(q, 2.3), bayer=bayer, diff_sigma=0.005
    )
    rgba_wrong = texture.rgba_texture(
        texture.rendered_images(q, 0.0), bayer=bayer, diff_sigma=0.005
    )
    assert rgba_right.shape == (96, 96, 4)
    assert np.median(rgba_right[12:-12, 12:-12, 3]) > 0.9
    assert np.median(rgba_wrong[12:-12, 12:-12, 3]) < np.median(rgba_right[12:-12, 12:-12, 3])


def test_rgba_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="shape"):
        texture.rgba_texture(np.zeros((3, 1, 8, 8), dtype=np.float32), bayer=None)
