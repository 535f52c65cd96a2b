"""The solver's compiled kernels against NumPy: packed (CCS) spectra, frames, clipping, shifts."""

from __future__ import annotations

import numpy as np
import pytest

from elphel_host.mfsr.frames import aligned, padded
from elphel_host.mfsr.kernels import (
    accumulate,
    fill_padded,
    packed_irfft2,
    packed_rfft2,
    place,
    predict,
    pseudo_data,
    shift_normal_equations,
    unpacked,
)

# even and odd sides: the packed columns and rows differ between them
SHAPES = [(6, 8), (7, 9), (6, 9), (7, 8), (33, 20)]


def _image(shape, seed):
    return np.random.default_rng(seed).random(shape, dtype=np.float32)


@pytest.mark.parametrize("shape", SHAPES)
def test_packed_spectrum_is_numpys_half_spectrum(shape):
    img = _image(shape, 1)
    want = np.fft.rfft2(img.astype(np.float64))
    got = unpacked(packed_rfft2(img))
    assert got.shape == want.shape
    assert np.abs(got - want).max() <= 1e-6 * np.abs(want).max()
    back = packed_irfft2(packed_rfft2(img))
    assert np.abs(back - img).max() <= 1e-6


@pytest.mark.parametrize("shape", SHAPES)
def test_accumulate_reads_packed_spectra_band_by_band(shape):
    rng = np.random.default_rng(2)
    ny, nx = shape
    nxh, n_alias, k = nx // 2 + 1, 4, 3
    imgs = [_image(shape, 10 + i) for i in range(k)]
    coef = (rng.normal(size=(k, n_alias)) + 1j * rng.normal(size=(k, n_alias))).astype(np.complex64)
    ry = np.exp(1j * rng.random((k, ny))).astype(np.complex64)
    rx = np.exp(1j * rng.random((k, nxh))).astype(np.complex64)
    rhs = np.zeros((n_alias, ny, nxh), np.complex64)
    spectra = tuple(packed_rfft2(f) for f in imgs)
    for r0 in range(0, ny, 4):
        accumulate(rhs, spectra, coef, ry, rx, first=r0, rows=min(4, ny - r0))
    want = sum(
        coef[i][:, None, None] * np.outer(ry[i], rx[i])[None] * np.fft.rfft2(imgs[i])[None]
        for i in range(k)
    )
    assert np.abs(rhs - want).max() <= 1e-5 * np.abs(want).max()


@pytest.mark.parametrize("shape", SHAPES)
def test_predict_writes_the_packed_spectrum_of_the_model(shape):
    rng = np.random.default_rng(3)
    ny, nx = shape
    nxh = nx // 2 + 1
    imgs = [_image(shape, 20 + a) for a in range(4)]
    Z = np.stack([np.fft.rfft2(f) for f in imgs]).astype(np.complex64)
    # real couplings and integer-frequency ramps (a circular shift): the model is a real
    # image, whose spectrum's packed columns need only their upper half
    coef = rng.normal(size=4).astype(np.complex64)
    shift = (2, 3)
    ry = np.exp(-2j * np.pi * np.arange(ny) * shift[0] / ny).astype(np.complex64)
    rx = np.exp(-2j * np.pi * np.arange(nxh) * shift[1] / nx).astype(np.complex64)
    out = np.empty(shape, np.float32)
    predict(out, coef, Z, ry, rx)
    want = np.fft.irfft2(np.outer(ry, rx) * np.tensordot(coef, Z, axes=1), s=shape)
    got = packed_irfft2(out)
    assert np.abs(got - want).max() <= 1e-5 * np.abs(want).max()


@pytest.mark.parametrize("shape", SHAPES)
def test_place_scatters_blocks_into_the_packed_spectrum(shape):
    ny, nx = shape
    img = _image(shape, 4)
    half = np.fft.rfft2(img).astype(np.complex64)
    spec = np.zeros(shape, np.float32)
    # the upper rows direct; the lower rows' conjugates onto their mirror rows (only the
    # packed columns u = 0 and nx / 2 land in the half spectrum), then the lower rows
    # direct (their packed columns follow from the upper rows)
    top, cols = ny // 2 + 1, np.arange(nx // 2 + 1)
    place(spec, half[:top], np.arange(top), cols, False)
    mirror = (-np.arange(top, ny)) % ny
    edge = np.where((cols == 0) | (2 * cols == nx), cols, -1)
    place(spec, half[top:], mirror, edge, True)
    place(spec, half[top:], np.arange(top, ny), cols, False)
    assert np.abs(packed_irfft2(spec) - img).max() <= 1e-5


@pytest.mark.parametrize("shift", [(0, 0), (2, -3), (-1, 4), (9, 0), (0, -12)])
def test_fill_padded_is_the_aligned_frame_mirror_padded(shift):
    frame, ref = _image((9, 12), 5), _image((9, 12), 6)
    pads = (3, 4, 2, 5)  # top, bottom, left, right
    out = np.full((9 + 7, 12 + 7), np.nan, np.float32)
    fill_padded(out, frame, ref, shift, (pads[0], pads[2]))
    moved, _ = aligned(frame, ref, shift)
    assert np.array_equal(out, padded(moved, pads, mode="reflect"))


@pytest.mark.parametrize("shift", [(0, 0), (2, -3), (-1, 4), (9, 0)])
def test_pseudo_data_on_the_rectangle_a_frame_covers(shift):
    rng = np.random.default_rng(7)
    frame, ref = _image((10, 13), 8), _image((10, 13), 9)
    pads = (2, 3, 4, 1)
    (h, w), (sy, sx) = frame.shape, shift
    pred = rng.random((15, 18), dtype=np.float32)
    y0, y1, x0, x1 = max(0, sy), min(h, h + sy), max(0, sx), min(w, w + sx)
    valid = (pads[0] + y0, pads[0] + max(y1, y0), pads[2] + x0, pads[2] + max(x1, x0))
    offset = (pads[0] + sy, pads[2] + sx)
    sample = np.empty(25, np.float32)
    out = pred.copy()
    n = pseudo_data(out, frame, offset, valid, np.float32(0.3), 3, sample)
    # the same with whole padded arrays and a mask
    moved, mask = aligned(frame, ref, shift)
    f, v = padded(moved, pads, mode="reflect"), padded(mask, pads, mode="zero")
    r = f - pred
    want = np.where(v, pred + np.clip(r, -0.3, 0.3), pred)
    assert np.array_equal(out, want.astype(np.float32))
    on = v & (np.arange(15)[:, None] % 3 == 0) & (np.arange(18)[None, :] % 3 == 0)
    assert n == on.sum()
    assert np.array_equal(sample[:n], np.abs(r[on]))


def test_shift_normal_equations_sum_the_voting_pixels():
    rng = np.random.default_rng(11)
    frame = _image((10, 13), 12)
    pred, dy, dx = (rng.random((15, 18), dtype=np.float32) for _ in range(3))
    offset, valid = (3, 2), (4, 13, 2, 14)  # covers frame rows 1..9, columns 0..11
    got = shift_normal_equations(pred, dy, dx, frame, offset, valid, 0.4)
    y0, y1, x0, x1 = valid
    r = (frame[y0 - 3 : y1 - 3, x0 - 2 : x1 - 2] - pred[y0:y1, x0:x1]).astype(np.float64)
    vote = np.abs(r) <= 0.4
    assert 0 < vote.sum() < vote.size  # some pixels vote, some do not
    gy, gx = dy[y0:y1, x0:x1][vote].astype(np.float64), dx[y0:y1, x0:x1][vote].astype(np.float64)
    want = (gy @ gy, gy @ gx, gx @ gx, gy @ r[vote], gx @ r[vote])
    assert np.allclose(got, want, rtol=1e-12, atol=0)
