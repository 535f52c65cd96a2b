"""A given PSF per image region (mfsr/regions.py): cells fused on their own, blended."""

from __future__ import annotations

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

from elphel_host.burst.io import write_burst
from elphel_host.cli import main
from elphel_host.mfsr.fuse import fuse_frames
from elphel_host.mfsr.metrics import psnr
from elphel_host.mfsr.psf import TAU_GRID
from elphel_host.mfsr.psf_spec import GivenGrid, GivenKernel
from elphel_host.mfsr.regions import cell_bounds
from elphel_host.mfsr.robust import reconstruct
from elphel_host.mfsr.robust_config import RobustConfig
from elphel_host.mfsr.synth import make_burst, random_shifts

#: The given PSFs' gain over one estimated PSF on the `varying` burst.
GIVEN_GAIN_DB = 1.0  # measured +1.71 dB (33.90 against 32.19)


def _image(name: str = "astronaut") -> np.ndarray:
    import skimage.data as sd

    img = getattr(sd, name)()
    img = img.mean(axis=2) if img.ndim == 3 else img
    return (np.asarray(img, np.float32) / 255.0).copy()


def _gauss(sigma: float, r: int = 4) -> np.ndarray:
    d = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-0.5 * (d / sigma) ** 2)
    return np.outer(g, g) / np.outer(g, g).sum()


@pytest.fixture(scope="module")
def varying():
    """A burst whose blur grows from 0.3 HR px on the left to 1.1 on the right."""
    hr = _image()
    sharp, soft = (cv2.GaussianBlur(hr, (0, 0), s) for s in (0.3, 1.1))
    t = np.clip((np.arange(hr.shape[1]) - 128) / 256, 0, 1)[None, :].astype(np.float32)
    seen = (1 - t) * sharp + t * soft
    shifts = random_shifts(16, seed=3, spread=2.0)
    return hr, make_burst(seen, shifts, scale=2, noise_sigma=0.01, seed=4)


def test_cell_bounds():
    assert cell_bounds(256, 2, 1) == [0, 128, 256]
    assert cell_bounds(250, 3, 2) == [0, 84, 166, 250]  # even for Bayer mosaics


def test_a_blur_that_varies_is_undone_per_region_when_given(varying):
    hr, frames = varying
    one = fuse_frames(frames, scale=2, config=RobustConfig())  # one PSF, estimated
    grid = np.stack([_gauss(0.3), _gauss(1.1)])[None]  # the lens's blur at each side
    two = fuse_frames(frames, scale=2, config=RobustConfig(psf=GivenGrid(grid)))
    psf = two.info["psf"]
    assert psf["model"] == "regions" and psf["regions"] == [1, 2]
    ((left, right),) = psf["cells"]
    assert left["columns"] == [0, 128] and right["columns"] == [128, 256]
    assert left["source"] == right["source"] == "given" and right["tau"] in TAU_GRID
    gain = psnr(hr, two.image, data_range=1.0, border=8) - psnr(
        hr, one.image, data_range=1.0, border=8
    )
    assert gain >= GIVEN_GAIN_DB, gain
    assert "shifts_refined" in two.info and "noise_sigma" in two.info


def test_the_same_psf_in_every_cell_blends_without_seams(varying):
    _, frames = varying
    k = _gauss(0.8)
    # one prior too (each cell would choose its own tau)
    config = RobustConfig(psf=GivenKernel(k), choose_tau=False)
    whole = fuse_frames(frames, scale=2, config=config)
    grid = np.broadcast_to(k, (2, 2, *k.shape))
    cells = fuse_frames(frames, scale=2, config=replace(config, psf=GivenGrid(grid)))
    assert cells.info["psf"]["regions"] == [2, 2]
    assert all(c["model"] == "kernel" for row in cells.info["psf"]["cells"] for c in row)
    assert psnr(whole.image, cells.image, data_range=1.0, border=8) > 40


def test_bayer_bursts_are_split_on_whole_colour_cells():
    hr = _image()[:256, :256]
    rgb = np.stack([hr, hr * 0.9, hr * 0.8], axis=-1)
    shifts = random_shifts(16, seed=5, spread=2.0)
    planes = [make_burst(rgb[..., c], shifts, scale=1, noise_sigma=0.005, seed=6) for c in range(3)]
    mosaics = []
    for k in range(16):
        m = planes[1][k].copy()  # GRBG
        m[0::2, 1::2] = planes[0][k][0::2, 1::2]
        m[1::2, 0::2] = planes[2][k][1::2, 0::2]
        mosaics.append(m)
    k = _gauss(0.5)
    config = RobustConfig(psf=GivenKernel(k), choose_tau=False)
    one = fuse_frames(mosaics, scale=2, bayer="GRBG", config=config).image
    grid = GivenGrid(np.broadcast_to(k, (2, 2, *k.shape)))
    four = fuse_frames(mosaics, scale=2, bayer="GRBG", config=replace(config, psf=grid))
    assert four.image.shape == one.shape == (512, 512, 3)
    assert np.isfinite(four.image).all()
    for c in range(3):
        assert psnr(one[..., c], four.image[..., c], data_range=1.0, border=16) > 30


def test_region_checks():
    frames = [np.zeros((100, 100), np.float32)] * 8
    grid = np.broadcast_to(_gauss(0.8), (2, 3, 9, 9))
    with pytest.raises(ValueError, match="psf regions 2x2 on 100x100 frames"):
        fuse_frames(frames, scale=2, config=RobustConfig(psf=GivenGrid(grid[:, :2])))
    assert GivenGrid(grid).regions == (2, 3)
    for bad in (np.ones((2, 9, 9)), np.ones((1, 9, 3, 3))):
        with pytest.raises(ValueError, match=r"1\.\.8 regions a side"):
            GivenGrid(bad)
    with pytest.raises(ValueError, match="allowed here: one PSF"):
        reconstruct(frames, [(0.0, 0.0)] * 8, scale=2, config=RobustConfig(psf=GivenGrid(grid)))


def test_cli_psf_grid(tmp_path, capsys, varying):
    _, frames = varying
    dn = [np.clip(np.rint(f * 4000), 0, 65535).astype(np.uint16) for f in frames]
    b = write_burst(tmp_path / "b", dn)
    out = str(tmp_path / "sr.tif")
    args = ["mfsr", str(b), "--scale", "2", "--out", out, "--json"]
    grid = tmp_path / "grid.npy"
    np.save(grid, np.broadcast_to(_gauss(0.7), (1, 2, 9, 9)))
    assert main([*args, "--psf", str(grid)]) == 0
    psf = json.loads(capsys.readouterr().out)["psf"]
    assert psf["regions"] == [1, 2] and psf["cells"][0][1]["source"] == "given"
