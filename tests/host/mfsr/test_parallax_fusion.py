"""Shift-and-add fusion with per-pixel parallax motion (`elphel depth --motion local`)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from elphel_host.mfsr.local_motion import (
    ParallaxModel,
    camera_view_disparity,
    fuse_parallax,
    pixel_disparity,
)

H, W, S = 48, 64, 2
# Two surfaces: the left half at disparity 1 px, the right half at 3 px.
DISPARITY = np.where(np.arange(W)[None, :] < W // 2, 1.0, 3.0).astype(np.float32) * np.ones(
    (H, 1), np.float32
)
# Frame k's shift per px of disparity: sub-pixel steps along a tilted axis, as the stage's.
MODEL = ParallaxModel(tuple((0.13 * k, 0.53 * k) for k in range(12)))


def scene(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """A texture with detail above the LR Nyquist frequency (0.5 cycle/px)."""
    return (
        0.5
        + 0.2 * np.sin(2 * np.pi * (0.31 * x + 0.07 * y))
        + 0.15 * np.sin(2 * np.pi * (0.66 * x - 0.23 * y + 0.3))
        + 0.1 * np.cos(2 * np.pi * (0.12 * x + 0.71 * y))
    ).astype(np.float32)


def burst(model: ParallaxModel) -> list[np.ndarray]:
    """Point-sampled frames: pixel q of frame k sees the point r = q + D(r) * v_k.

    D belongs to the scene point (frame 0's grid), so in frame k the edge has moved: where
    both surfaces map to q the near one (D = 3) hides the far one.
    """
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float32)
    out = []
    for vy, vx in model.per_disparity:
        near = xs + 3 * vx >= W // 2
        d = np.where(near | (xs + vx >= W // 2), 3.0, 1.0).astype(np.float32)
        out.append(scene(ys + d * vy, xs + d * vx))
    return out


def truth() -> np.ndarray:
    """The scene at the output pixels' centres (LR pixel i centred at S i + (S - 1) / 2)."""
    u = (np.arange(H * S) - (S - 1) / 2) / S
    v = (np.arange(W * S) - (S - 1) / 2) / S
    yy, xx = np.meshgrid(u, v, indexing="ij")
    return scene(yy, xx)


def rms(a: np.ndarray, b: np.ndarray) -> float:
    m = 8  # the border, where some shifts leave the frame
    return float(np.sqrt(np.mean((a[m:-m, m:-m] - b[m:-m, m:-m]) ** 2)))


def test_per_pixel_motion_recovers_what_one_frame_aliases() -> None:
    frames = burst(MODEL)
    fused, info = fuse_parallax(frames, MODEL, DISPARITY, scale=S, bayer=None, threads=2)
    assert fused.shape == (H * S, W * S) and fused.dtype == np.float32
    assert info["frames"] == 12 and info["max_shift_px"] == pytest.approx(
        3 * np.hypot(1.43, 5.83), abs=1e-3
    )
    bicubic = cv2.resize(frames[0], (W * S, H * S), interpolation=cv2.INTER_CUBIC)
    # One shift for the whole frame (the median disparity) misplaces one of the two surfaces.
    flat = np.full_like(DISPARITY, 2.0)
    global_, _ = fuse_parallax(frames, MODEL, flat, scale=S, bayer=None)
    ref = truth()
    assert rms(fused, ref) < 0.45 * rms(bicubic, ref)  # measured 0.38
    assert rms(fused, ref) < 0.4 * rms(global_, ref)  # 0.32
    # Around the depth edge (LR columns 28..36) frame k's pixels left of the edge see the
    # near surface, which hides the far one: taking them for far points gave 0.16 here.
    edge = np.s_[16:-16, 56:72]
    assert float(np.sqrt(np.mean((fused[edge] - ref[edge]) ** 2))) < 0.12  # 0.09


def test_bands_and_threads_do_not_change_the_result() -> None:
    frames = burst(MODEL)
    one, _ = fuse_parallax(frames, MODEL, DISPARITY, scale=S, bayer=None, threads=1, band_rows=H)
    many, _ = fuse_parallax(frames, MODEL, DISPARITY, scale=S, bayer=None, threads=2, band_rows=7)
    np.testing.assert_allclose(many, one, rtol=0, atol=1e-5)


def test_bayer_planes_and_holes_are_filled() -> None:
    mosaic = [f * 1000 for f in burst(ParallaxModel(((0.0, 0.0),)))]
    fused, info = fuse_parallax(
        mosaic, ParallaxModel(((0.0, 0.0),)), DISPARITY, scale=4, bayer="GRBG"
    )
    assert fused.shape == (H * 4, W * 4, 3) and np.isfinite(fused).all()
    # one frame of a mosaic leaves most output pixels of red and blue without a sample
    assert 0.3 < info["filled_fraction"] < 0.95
    assert 300 < float(fused.mean()) < 700


def test_bad_input() -> None:
    frames = burst(MODEL)
    with pytest.raises(ValueError, match="12 parallax entries for 11 frames"):
        fuse_parallax(frames[:11], MODEL, DISPARITY, scale=S, bayer=None)
    with pytest.raises(ValueError, match=r"disparity map \(48, 32\), frames \(48, 64\)"):
        fuse_parallax(frames, MODEL, DISPARITY[:, :32], scale=S, bayer=None)


def test_camera_view_moves_depth_edges_by_half_the_disparity() -> None:
    centre = np.where(np.arange(40)[None, :] < 20, 4.0, 1.0).astype(np.float32) * np.ones(
        (8, 1), np.float32
    )
    # The camera at x = -0.5 sees the near (D = 4) surface 2 px further right.
    left = camera_view_disparity(centre, (-0.5, 0.0))
    assert (left[:, :21] == 4.0).all() and (left[:, 23:] == 1.0).all()
    right = camera_view_disparity(centre, (0.5, 0.0))
    assert (right[:, :17] == 4.0).all() and (right[:, 20:] == 1.0).all()
    assert camera_view_disparity(centre, (0.0, 0.0)) is centre


def test_pixel_disparity_puts_tile_values_at_tile_centres() -> None:
    field = np.arange(12, dtype=np.float32).reshape(3, 4)
    px = pixel_disparity(field, (24, 32))
    # tile (ty, tx) is centred between pixels 8t + 3 and 8t + 4
    assert px[11:13, 11:13].mean() == pytest.approx(field[1, 1])
