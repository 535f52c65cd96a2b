"""What the robust method is told about the optics: one typed value, :data:`PsfSpec`.

* :class:`NoBlur` - the pixel aperture alone (``--psf none``);
* :class:`EstimateBlur` - the blur estimated from the burst (``--psf auto``, the default);
* :class:`~elphel_host.mfsr.gaussian_psf.GaussianPsf` - a given Gaussian on the output's
  HR grid (``--psf sigma=S``);
* :class:`GivenKernel` - a given PSF on the output's HR grid (``--psf FILE.npy``);
* :class:`GivenGrid` - one given PSF per image region (``--psf FILE.npy`` with a 4-D
  array, ``--psf quad=DIR``), the cells fused apart and blended
  (:mod:`elphel_host.mfsr.regions`).

Given kernels and grids may carry each colour's own PSFs for a Bayer burst and the frame
size they were made for. :func:`parse_psf` reads ``--psf``; the value is resolved into
the optics a reconstruction uses by :func:`elphel_host.mfsr.robust.resolve_psf`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elphel_host.mfsr.gaussian_psf import MAX_KERNEL, GaussianPsf

F64 = NDArray[np.float64]

#: Largest given Gaussian sigma (HR px).
MAX_SIGMA = 3.0
#: Most regions a side of a given grid.
MAX_REGIONS = 8


@dataclass(frozen=True)
class NoBlur:
    """The pixel aperture alone: nothing deconvolved, the prior's tau as configured."""


@dataclass(frozen=True)
class EstimateBlur:
    """The blur (and the prior's tau) estimated from the burst (:mod:`elphel_host.mfsr.psf`)."""


def check_kernel(kernel: Any, source: str = "kernel") -> F64:
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


def check_kernel_grid(grid: Any, source: str = "grid") -> F64:
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


def _check_frame(frame: tuple[int, int] | None) -> tuple[int, int] | None:
    if frame is None:
        return None
    if len(frame) != 2 or min(frame) < 1:
        raise ValueError(f"frame={frame}; allowed: (height, width) of at least 1 px")
    return (int(frame[0]), int(frame[1]))


@dataclass(frozen=True)
class GivenKernel:
    """A given PSF on the output's HR grid.

    Attributes
    ----------
    kernel
        2-D, odd sides up to 31 (:func:`check_kernel`); stored with sum 1.
    rgb
        A Bayer burst's red, green and blue PSFs ``(3, h, w)``, each colour reconstructed
        with its own; None: ``kernel`` for every colour.
    frame
        (height, width) of the frames it was made for (e.g. a quad's calibration); frames
        of another size are refused. None: any.
    """

    kernel: F64 = field(repr=False)
    rgb: F64 | None = field(default=None, repr=False)
    frame: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "kernel", check_kernel(self.kernel))
        object.__setattr__(self, "frame", _check_frame(self.frame))
        if self.rgb is None:
            return
        arr = np.asarray(self.rgb, dtype=np.float64)
        if arr.ndim != 3 or len(arr) != 3:
            raise ValueError(f"rgb: shape {arr.shape}; allowed: (3, h, w), one PSF per colour")
        object.__setattr__(
            self, "rgb", np.stack([check_kernel(k, f"rgb[{c}]") for c, k in enumerate(arr)])
        )


@dataclass(frozen=True)
class GivenGrid:
    """Given PSFs per image region, ``(rows, columns, h, w)`` on the output's HR grid.

    Attributes
    ----------
    grid
        One PSF per region (:func:`check_kernel_grid`).
    rgb
        Each colour's grid ``(3, rows, columns, h, w)`` (R, G, B) for a Bayer burst; None:
        ``grid`` for every colour.
    frame
        (height, width) of the frames it was made for; None: any.
    """

    grid: F64 = field(repr=False)
    rgb: F64 | None = field(default=None, repr=False)
    frame: tuple[int, int] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "grid", check_kernel_grid(self.grid))
        object.__setattr__(self, "frame", _check_frame(self.frame))
        if self.rgb is None:
            return
        arr = np.asarray(self.rgb, dtype=np.float64)
        if arr.ndim != 5 or len(arr) != 3 or arr.shape[1:3] != self.regions:
            raise ValueError(
                f"rgb: shape {arr.shape}; allowed: (3, {self.regions[0]}, {self.regions[1]}, "
                "h, w), each colour's grid of the same regions"
            )
        grids = [check_kernel_grid(g, f"rgb[{c}]") for c, g in enumerate(arr)]
        object.__setattr__(self, "rgb", np.stack(grids))

    @property
    def regions(self) -> tuple[int, int]:
        """(rows, columns) of regions."""
        return int(self.grid.shape[0]), int(self.grid.shape[1])

    def cell(self, iy: int, ix: int) -> GivenKernel:
        """The PSF of region (iy, ix)."""
        rgb = None if self.rgb is None else self.rgb[:, iy, ix]
        return GivenKernel(self.grid[iy, ix], rgb=rgb)


#: Everything the robust method can be told about the optics.
PsfSpec = NoBlur | EstimateBlur | GaussianPsf | GivenKernel | GivenGrid


def load_kernel(path: str | Path) -> GivenKernel | GivenGrid:
    """A PSF from a ``.npy`` file (:func:`check_kernel`), or a 4-D grid of them per region."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"--psf {str(path)!r}: no such file")
    try:
        data = np.load(p, allow_pickle=False)
    except ValueError as e:
        raise ValueError(f"{p}: not a .npy array ({e})") from e
    if np.ndim(data) == 4:
        return GivenGrid(check_kernel_grid(data, str(p)))
    return GivenKernel(check_kernel(data, str(p)))


def parse_psf(text: str) -> PsfSpec:
    """``--psf`` values: ``auto``, ``none``, ``sigma=S`` (HR px), FILE.npy.

    Raises ValueError naming the value and what is allowed.
    """
    t = text.strip().lower()
    if t.endswith(".npy"):
        return load_kernel(text.strip())
    if t == "auto":
        return EstimateBlur()
    if t == "none":
        return NoBlur()
    if t.startswith("sigma="):
        try:
            s = float(t[len("sigma=") :])
        except ValueError:
            s = float("nan")
        if not 0.0 <= s <= MAX_SIGMA:
            raise ValueError(f"--psf {text!r}: sigma must be a number 0..{MAX_SIGMA} (HR px)")
        return GaussianPsf.round(s) if s > 0 else NoBlur()
    raise ValueError(
        f"--psf {text!r}; allowed: auto, none, sigma=S (S in HR px, 0..{MAX_SIGMA}), a "
        "PSF kernel FILE.npy (2-D, or 4-D: one PSF per region) or quad=QUAD_DIR[,camera=N]"
    )
