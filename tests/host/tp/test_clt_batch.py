"""The CLT's three forms agree: production (clt.batch), reference (clt.reference), definition.

`camera_spectra` returns, per colour, the sum of that colour's lattice spectra times the
square root of the colour weight, on the kept frequencies. Built here from
`clt.reference.lattice_spectra` (float32, the same arithmetic in another order) and from
`clt.transform.clt_tiles` of each colour plane (float64, the definition).
"""

from __future__ import annotations

import numpy as np
import pytest

from elphel_host.tp import bayer, clt
from elphel_host.tp.clt import batch, reference
from elphel_host.tp.config import TpConfig
from elphel_host.tp.geometry import TilePlacement
from elphel_host.tp.tile_pass import colour_masks

H, W, PAD = 64, 80, 24
PATTERNS = [None, "GRBG", "RGGB", "GBRG", "BGGR"]
# float32 against float32 (another order of the same sums) and against the float64
# definition; coefficients reach ~9 (mono) and ~2 (Bayer) for samples in [0, 1), and the
# measured errors are ~5e-6 (mono) and ~6e-7 (Bayer).
TOL_REFERENCE = 2e-5
TOL_DEFINITION = 3e-5


def random_tiles(seed: int, n: int, *, uniform: bool) -> TilePlacement:
    """Tiles of all four parity classes, some hanging over the border."""
    rng = np.random.default_rng(seed)
    left = rng.integers(-6, W - 10, size=n).astype(np.int64)
    top = rng.integers(-6, H - 10, size=n).astype(np.int64)
    left[:4], top[:4] = [10, 11, 10, 11], [20, 20, 21, 21]
    if uniform:  # one shift for all tiles: the fast path's first-pass branch
        sx, sy = np.full(n, rng.uniform(-0.5, 0.5)), np.full(n, rng.uniform(-0.5, 0.5))
    else:
        sx, sy = rng.uniform(-0.5, 0.5, size=n), rng.uniform(-0.5, 0.5, size=n)
    return TilePlacement(left_x=left, shift_x=sx, top_y=top, shift_y=sy)


def fast(
    image: np.ndarray, pattern: str | None, at: TilePlacement
) -> tuple[list[np.ndarray], batch.CameraTransform]:
    weights = colour_masks(pattern, TpConfig())
    tr = batch.camera_transform(pattern, weights, green_band=TpConfig().green_band, pad=PAD)
    return [np.asarray(z) for z in batch.camera_spectra(image, tr, at)], tr


def compact(full: np.ndarray, fset: batch.FrequencySet, n: int) -> np.ndarray:
    """Full layout ``(T, 8 kh, 2, 8 kv)`` -> compact ``(T, 2, n)`` on the first n frequencies."""
    return full[:, fset.kh[:n], :, fset.kv[:n]].transpose(1, 2, 0)


def weighted(per_colour: list[np.ndarray], pattern: str | None) -> list[np.ndarray]:
    root = np.sqrt(np.maximum(colour_masks(pattern, TpConfig()), 0.0))
    return [z * root[c] for c, z in enumerate(per_colour)]


def fast_layout(quadrants: np.ndarray) -> np.ndarray:
    z1, z2 = clt.to_complex(quadrants)
    return np.stack([np.swapaxes(z2, -1, -2), np.swapaxes(z1, -1, -2)], axis=-2)


@pytest.mark.parametrize("uniform", [False, True], ids=["per-tile-shift", "one-shift"])
@pytest.mark.parametrize("pattern", PATTERNS, ids=lambda p: p or "mono")
def test_fast_path_equals_reference_lattice_transform(pattern: str | None, uniform: bool) -> None:
    image = np.random.default_rng(7).random((H, W)).astype(np.float32)
    at = random_tiles(8, 40, uniform=uniform)
    got, tr = fast(image, pattern, at)
    ncol = len(bayer.colour_names(pattern))
    sums = [np.zeros((40, 8, 2, 8), dtype=np.complex64) for _ in range(ncol)]
    for lat in bayer.lattices(pattern):
        sub = bayer.sublattice(image, lat, pad=PAD)
        sums[lat.colour] += reference.lattice_spectra(sub, lat, at, pad=PAD)
    want = weighted(sums, pattern)
    assert len(got) == ncol
    for c in range(ncol):
        ref = compact(want[c], tr.fset, tr.colour_sizes[c])
        assert got[c].shape == ref.shape == (40, 2, tr.colour_sizes[c])
        assert got[c].dtype == np.complex64
        assert np.abs(got[c] - ref).max() <= TOL_REFERENCE


@pytest.mark.parametrize("pattern", PATTERNS, ids=lambda p: p or "mono")
def test_fast_path_equals_the_definition_on_colour_planes(pattern: str | None) -> None:
    image = np.random.default_rng(9).random((H, W))
    n = 30
    rng = np.random.default_rng(10)
    at = TilePlacement(
        left_x=rng.integers(0, W - 16, size=n).astype(np.int64),
        shift_x=rng.uniform(-0.5, 0.5, size=n),
        top_y=rng.integers(0, H - 16, size=n).astype(np.int64),
        shift_y=rng.uniform(-0.5, 0.5, size=n),
    )
    got, tr = fast(image.astype(np.float32), pattern, at)
    ncol = len(bayer.colour_names(pattern))
    planes = np.zeros((ncol, H, W))
    for lat in bayer.lattices(pattern):
        sl = (slice(lat.row, None, lat.step), slice(lat.col, None, lat.step))
        planes[lat.colour][sl] = image[sl] * lat.scale
    sums = []
    for plane in planes:
        tiles = np.stack(
            [plane[y : y + 16, x : x + 16] for x, y in zip(at.left_x, at.top_y, strict=True)]
        )
        sums.append(fast_layout(clt.clt_tiles(tiles, shift_x=at.shift_x, shift_y=at.shift_y)))
    want = weighted(sums, pattern)
    for c in range(ncol):
        ref = compact(want[c], tr.fset, tr.colour_sizes[c])
        assert np.abs(got[c] - ref).max() <= TOL_DEFINITION


@pytest.mark.parametrize("pattern", [None, "GRBG", "RGGB"])
def test_lattice_spectra_equal_clt_of_colour_plane(pattern: str | None) -> None:
    rng = np.random.default_rng(5)
    img = rng.random((64, 64)).astype(np.float32)
    lx = np.array([13, 14, 20])
    ly = np.array([9, 10, 22])
    sx = np.array([0.3, -0.4, 0.1])
    sy = np.array([-0.2, 0.5, 0.0])
    for lat in bayer.lattices(pattern):
        plane = np.zeros_like(img)
        sl = (slice(lat.row, None, lat.step), slice(lat.col, None, lat.step))
        plane[sl] = img[sl] * lat.scale
        z = reference.lattice_spectra(
            bayer.sublattice(img, lat, pad=20), lat, TilePlacement(lx, sx, ly, sy), pad=20
        )
        tiles = np.stack(
            [plane[y : y + 16, x : x + 16] for x, y in zip(lx, ly, strict=True)]
        ).astype(np.float64)
        ref = fast_layout(clt.clt_tiles(tiles, shift_x=sx, shift_y=sy))
        assert np.allclose(z, ref, atol=2e-5)
