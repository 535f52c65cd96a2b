"""Aberration kernels: CLT-domain product against direct convolution, and in the pipeline."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import tifffile
from scipy import ndimage

from elphel_host.tp import clt, io, kernels, processor
from elphel_host.tp.config import TpConfig
from elphel_host.tp.geometry import IDEAL_POSITIONS
from elphel_host.tp.images import QuadImages


def texture(size: int, seed: int = 0, band: float = 0.25) -> np.ndarray:
    rng = np.random.default_rng(seed)
    f = np.fft.fftfreq(size)
    fr = np.hypot(f[:, None], f[None, :])
    spec = (rng.normal(size=(size, size)) + 1j * rng.normal(size=(size, size))) / np.maximum(
        fr, 1 / size
    )
    img = np.fft.ifft2(spec * (fr < band)).real
    return (img - img.min()) / (img.max() - img.min())


def test_impulse_is_identity_and_shift_is_rotation() -> None:
    k = np.zeros((15, 15))
    k[7, 7] = 1.0
    kc = kernels.kernel_clt(k)
    assert np.allclose(kc[0], 1.0) and np.allclose(kc[1:], 0.0)
    k[7, 7], k[7, 8] = 0.0, 1.0  # move by +1 px in x
    kc = kernels.kernel_clt(k)
    theta = np.pi * (2 * np.arange(8) + 1) / 16
    assert np.allclose(kc[0], np.cos(theta)[None, :]) and np.allclose(kc[1], np.sin(theta)[None, :])


def test_clt_product_matches_direct_convolution_and_odd_odd_sign() -> None:
    img = texture(96)
    yy, xx = np.mgrid[-7:8, -7:8]
    k = np.exp(-(xx**2 + yy**2 - 1.4 * xx * yy) / (2 * 0.8**2))  # diagonal: strong odd-odd part
    k /= k.sum()
    direct = ndimage.convolve(img, k, mode="wrap")
    inner = (slice(16, -16), slice(16, -16))
    c = clt.clt_image(img)
    errors = {}
    for sign in ("odd-odd", "odd-x"):
        out = clt.iclt_image(kernels.convolve_clt(c, kernels.kernel_clt(k, odd_odd_sign=sign)))
        errors[sign] = np.abs(out - direct)[inner].max()
        if sign == "odd-odd":
            d = direct[inner] - direct[inner].mean()
            o = out[inner] - out[inner].mean()
            assert 0.95 < (o * d).sum() / (d * d).sum() < 1.0  # the reference saw 0.96-0.98
    effect = np.abs(direct - img)[inner].max()
    assert errors["odd-odd"] < 0.3 * effect
    assert errors["odd-x"] > 1.5 * errors["odd-odd"]


def blurred_quad(*, kernel_for_others: bool) -> tuple[QuadImages, float]:
    """Camera 1 blurred by an off-centre kernel (centroid +0.3 px in x); disparity 1.0."""
    size, disparity = 128, 1.0
    f = np.fft.fftfreq(size)
    fy, fx = f[:, None], f[None, :]
    base = np.fft.fft2(texture(size, seed=3))
    yy, xx = np.mgrid[-7:8, -7:8]
    blur = np.exp(-((xx - 0.3) ** 2 + yy**2) / (2 * 0.9**2))
    blur /= blur.sum()
    ident = np.zeros((15, 15))
    ident[7, 7] = 1.0
    views = []
    for i, (px, py) in enumerate(IDEAL_POSITIONS):
        img = np.fft.ifft2(base * np.exp(2j * np.pi * disparity * (fx * px + fy * py))).real
        views.append(ndimage.convolve(img, blur, mode="wrap") if i == 1 else img)
    ks = np.stack([blur if i != 1 else ident for i in range(4)])[:, None, None, None]
    return QuadImages(
        np.asarray(views, dtype=np.float32), kernels=ks if kernel_for_others else None
    ), disparity


def test_kernels_remove_the_bias_of_an_aberrated_camera() -> None:
    inner = (slice(2, -2), slice(2, -2))
    cfg = TpConfig(threads=1)
    q, d = blurred_quad(kernel_for_others=False)
    raw = processor.disparity_map(q, config=cfg)
    q, d = blurred_quad(kernel_for_others=True)
    fixed = processor.disparity_map(q, config=cfg)
    bias_raw = abs(np.mean(raw["disparity_hor"][inner]) - d)
    bias_fixed = abs(np.mean(fixed["disparity_hor"][inner]) - d)
    assert bias_raw > 0.1  # camera 1 looks shifted by ~0.3 px in the top pair
    assert bias_fixed < 0.3 * bias_raw


def test_kernels_from_quad_dir(tmp_path: Path) -> None:
    q, _ = blurred_quad(kernel_for_others=True)
    cams = []
    for i in range(4):
        tifffile.imwrite(tmp_path / f"cam{i}.tif", np.round(q.images[i] * 4095).astype(np.uint16))
        cams.append({"file": f"cam{i}.tif", "position": list(IDEAL_POSITIONS[i])})
    assert q.kernels is not None
    np.save(tmp_path / "kernels.npy", q.kernels)
    manifest = {
        "version": 1,
        "cameras": cams,
        "bayer": None,
        "full_scale_dn": 4095,
        "kernels": {"file": "kernels.npy", "step": 16},
    }
    (tmp_path / "quad.json").write_text(json.dumps(manifest))
    loaded = io.read_quad_dir(tmp_path).quad
    assert loaded.kernels is not None and loaded.kernels.shape == (4, 1, 1, 1, 15, 15)
    manifest["kernels"] = {"file": "kernels.npy", "step": 0}
    (tmp_path / "quad.json").write_text(json.dumps(manifest))
    with pytest.raises(Exception, match=r"kernels\.step=0"):
        io.read_quad_dir(tmp_path)


def test_bad_kernel_shape_rejected() -> None:
    with pytest.raises(ValueError, match=r"shape \(15, 15\)"):
        kernels.kernel_clt(np.zeros((7, 7)))
    with pytest.raises(Exception, match="kernels must have shape"):
        QuadImages(np.zeros((4, 16, 16), dtype=np.float32), kernels=np.zeros((4, 1, 15, 15)))


def test_simulated_aberrations_and_their_kernel_file(tmp_path: Path) -> None:
    from elphel_sim import quad as simquad

    rig = simquad.QuadRig(width=384, height=288)
    scene = simquad.standard_scene(rig, seed=2)
    truth = simquad.tile_truth(scene)
    blur = simquad.aberrations(rig, seed=5)
    assert blur.psfs.shape[:2] == (4, 3)
    raw = simquad.render_quad(scene, seed=None, blur=blur)
    fix = simquad.correction_kernels(blur, bayer=rig.bayer)
    names = [n for n in truth.names if n.startswith("fronto")]
    mask = np.isin(truth.label, [truth.names.index(n) for n in names]) & truth.interior
    rms = {}
    for use in (False, True):
        root = simquad.write_quad_dir(
            tmp_path / str(use), raw, rig, kernels=(fix, blur.step) if use else None
        )
        dsi = processor.disparity_map(io.read_quad_dir(root).quad)
        rms[use] = np.sqrt(np.mean((dsi["disparity"] - truth.disparity)[mask] ** 2))
    # different off-centre PSFs per camera bias the disparity; the kernels undo much of it
    assert rms[False] > 0.1
    assert rms[True] < 0.75 * rms[False]
