"""PSFs a user gives: ``--psf`` values, a kernel on the HR grid, a grid of them per region."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elphel_host.mfsr.psf import MAX_SIGMA, NO_BLUR, PsfEstimate

MAX_KERNEL = 31


def check_kernel(kernel: Any, source: str = "kernel") -> NDArray[np.float64]:
    """A PSF on the HR grid: 2-D, odd sides up to 31, finite, sum > 0; returned with sum 1."""
    k = np.asarray(kernel, dtype=np.float64)
    if k.ndim != 2 or k.shape[0] % 2 == 0 or k.shape[1] % 2 == 0 or max(k.shape) > MAX_KERNEL:
        raise ValueError(
            f"{source}: shape {k.shape}; allowed: 2-D, odd sides up to {MAX_KERNEL} "
            "(centred on the middle sample, HR px)"
        )
    if not np.all(np.isfinite(k)) or not k.sum() > 0:
        raise ValueError(f"{source}: allowed: finite values with a positive sum")
    return np.asarray(k / k.sum(), dtype=np.float64)


MAX_REGIONS = 8


def check_kernel_grid(grid: Any, source: str = "psf_grid") -> NDArray[np.float64]:
    """PSFs per region, ``(ky, kx, h, w)``: 1..8 cells a side, each kernel as `check_kernel`."""
    g = np.asarray(grid, dtype=np.float64)
    if g.ndim != 4 or not (1 <= g.shape[0] <= MAX_REGIONS and 1 <= g.shape[1] <= MAX_REGIONS):
        raise ValueError(
            f"{source}: shape {g.shape}; allowed: (rows, columns, h, w) with 1..{MAX_REGIONS} "
            "regions a side, one PSF per region"
        )
    cells = [
        [check_kernel(g[iy, ix], f"{source}[{iy}, {ix}]") for ix in range(g.shape[1])]
        for iy in range(g.shape[0])
    ]
    return np.asarray(cells, dtype=np.float64)


def load_kernel(path: str | Path) -> NDArray[np.float64]:
    """A PSF from a ``.npy`` file (:func:`check_kernel`), or a 4-D grid of them per region."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"--psf {str(path)!r}: no such file")
    try:
        data = np.load(p, allow_pickle=False)
    except ValueError as e:
        raise ValueError(f"{p}: not a .npy array ({e})") from e
    if np.ndim(data) == 4:
        return check_kernel_grid(data, str(p))
    return check_kernel(data, str(p))


def parse_psf(text: str) -> PsfEstimate | None:
    """``--psf`` values: ``auto`` (None: estimate), ``none``, ``sigma=S`` (HR px), FILE.npy.

    Raises ValueError naming the value and what is allowed.
    """
    if text.strip().lower().endswith(".npy"):
        return PsfEstimate("kernel", 0.0, "given", kernel=load_kernel(text.strip()))
    t = text.strip().lower()
    if t == "auto":
        return None
    if t == "none":
        return NO_BLUR
    if t.startswith("sigma="):
        try:
            s = float(t[len("sigma=") :])
        except ValueError:
            s = float("nan")
        if not 0.0 <= s <= MAX_SIGMA:
            raise ValueError(f"--psf {text!r}: sigma must be a number 0..{MAX_SIGMA} (HR px)")
        return PsfEstimate("gaussian" if s > 0 else "none", s, "given")
    raise ValueError(
        f"--psf {text!r}; allowed: auto, none, sigma=S (S in HR px, 0..{MAX_SIGMA}) or a "
        "PSF kernel FILE.npy (2-D, or 4-D: one PSF per region)"
    )
