"""PSFs from the tile processor's aberration-correction kernels: ``--psf quad=DIR``.

A quad directory's kernel file (docs/tile-processor.md) holds, per camera, colour and
grid cell, a kernel that turns the lens's point-spread function there into one common
Gaussian (``kernels.target_sigma_px``): ``psf * kernel = target``. Each cell's PSF is
recovered from its kernel as the Gaussian (elliptical, off-centre) whose product with
the kernel's spectrum best matches the target's, weighted by the target's spectrum: the
kernel is only known up to the sensor's Nyquist frequency, and a parametric PSF carries
it beyond, where super-resolution needs it. The PSFs are drawn on the output grid and
laid out as one per MFSR region, the nearest cell's (as the tile processor uses the
nearest kernel per tile).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tifffile
from numpy.typing import NDArray
from scipy.optimize import least_squares

from elphel_host.errors import InputFormatError
from elphel_host.mfsr.psf_given import MAX_KERNEL, MAX_REGIONS
from elphel_host.tp.io import MANIFEST, QuadManifest
from elphel_host.tp.kernel_file import load_kernels

F64 = NDArray[np.float64]

#: DFT size the kernels' spectra are taken at.
N_FFT = 64


@dataclass(frozen=True)
class GaussianPsf:
    """An elliptical Gaussian PSF in sensor px: covariance ``cov`` (y, x) and centre offset."""

    cov: F64  # (2, 2), rows/columns (y, x)
    offset: tuple[float, float]  # (dy, dx)

    @property
    def sigmas(self) -> tuple[float, float]:
        """Standard deviations along the principal axes, larger first."""
        ev = np.linalg.eigvalsh(self.cov)
        return float(np.sqrt(max(ev[1], 0.0))), float(np.sqrt(max(ev[0], 0.0)))

    def on_grid(self, scale: int) -> F64:
        """The PSF on the output grid (``scale`` output px per sensor px), sum 1, odd sides."""
        cov = self.cov * scale * scale
        oy, ox = self.offset[0] * scale, self.offset[1] * scale
        reach = 3.0 * float(np.sqrt(np.linalg.eigvalsh(cov)[1])) + max(abs(oy), abs(ox))
        half = int(min(np.ceil(reach), MAX_KERNEL // 2))
        y, x = np.mgrid[-half : half + 1, -half : half + 1].astype(np.float64)
        d = np.stack([y - oy, x - ox], axis=-1)
        q = np.einsum("...i,ij,...j->...", d, np.linalg.inv(cov), d)
        k = np.exp(-0.5 * q)
        return np.asarray(k / k.sum(), dtype=np.float64)


def psf_from_kernel(kernel: NDArray[np.floating], target_sigma_px: float) -> GaussianPsf:
    """The Gaussian PSF that ``kernel`` (15x15, row = 7 + dy) turns into the target Gaussian."""
    k = np.asarray(kernel, dtype=np.float64)
    if k.shape != (15, 15) or not np.all(np.isfinite(k)):
        raise ValueError(f"kernel of shape {k.shape}; allowed: (15, 15), finite")
    big = np.zeros((N_FFT, N_FFT))
    big[:15, :15] = k
    spec = np.fft.fft2(np.roll(big, (-7, -7), axis=(0, 1)))  # centred on (0, 0)
    f = np.fft.fftfreq(N_FFT)
    fy, fx = np.meshgrid(f, f, indexing="ij")
    two_pi2 = 2.0 * np.pi**2
    target = np.exp(-two_pi2 * target_sigma_px**2 * (fy * fy + fx * fx))
    weight = target.ravel()

    def cov_of(p: F64) -> F64:
        lo = np.array([[np.exp(p[0]), 0.0], [p[2], np.exp(p[1])]])
        return np.asarray(lo @ lo.T)

    def residual(p: F64) -> F64:
        c = cov_of(p)
        quad = c[0, 0] * fy * fy + 2 * c[0, 1] * fy * fx + c[1, 1] * fx * fx
        model = np.exp(-two_pi2 * quad - 2j * np.pi * (fy * p[3] + fx * p[4])) * spec
        r = (model - target).ravel() * weight
        return np.concatenate([r.real, r.imag])

    start = np.log(max(0.5 * target_sigma_px, 0.05))
    fit = least_squares(residual, np.array([start, start, 0.0, 0.0, 0.0]), method="lm")
    return GaussianPsf(cov=cov_of(fit.x), offset=(float(fit.x[3]), float(fit.x[4])))


@dataclass(frozen=True)
class QuadPsfs:
    """A quad camera's PSFs per kernel cell, and the frame they cover."""

    psfs: list[list[GaussianPsf]]  # [ky][kx]
    step: int
    frame: tuple[int, int]  # (height, width) of the quad's images

    def grid(self, scale: int) -> F64:
        """PSFs on the output grid per MFSR region, ``(rows, columns, h, w)``.

        Up to :data:`MAX_REGIONS` regions a side, each the PSF of the kernel cell nearest
        its centre, padded to one size.
        """
        h, w = self.frame
        ky, kx = len(self.psfs), len(self.psfs[0])
        rows, cols = min(ky, MAX_REGIONS), min(kx, MAX_REGIONS)
        kernels = [
            [
                self.psfs[min(int((i + 0.5) * h / rows) // self.step, ky - 1)][
                    min(int((j + 0.5) * w / cols) // self.step, kx - 1)
                ].on_grid(scale)
                for j in range(cols)
            ]
            for i in range(rows)
        ]
        side = max(k.shape[0] for row in kernels for k in row)
        out = np.zeros((rows, cols, side, side))
        for i, row in enumerate(kernels):
            for j, k in enumerate(row):
                m = (side - k.shape[0]) // 2
                out[i, j, m : m + k.shape[0], m : m + k.shape[1]] = k
        return out


def quad_psfs(quad_dir: str | Path, camera: int = 0) -> QuadPsfs:
    """The PSFs of ``camera`` recovered from a quad directory's kernel file.

    Bayer kernels (colours R, B, G): green's, the colour MFSR estimates its PSF on.

    Raises
    ------
    InputFormatError
        No kernel file, no ``target_sigma_px`` beside it, a bad camera or array shape.
    """
    root = Path(quad_dir)
    manifest = QuadManifest.read(root)
    source = root / MANIFEST
    spec = manifest.kernels
    if spec is None:
        raise InputFormatError(f"{source}: no 'kernels' entry; allowed: a quad with kernels")
    if spec.target_sigma_px is None:
        raise InputFormatError(
            f"{source}: kernels.target_sigma_px is missing; the PSFs cannot be recovered "
            "from the kernels without the Gaussian they correct to (sensor px): add it"
        )
    if not 0 <= camera < len(manifest.cameras):
        raise InputFormatError(f"camera={camera}; allowed: 0..{len(manifest.cameras) - 1}")
    kernels = load_kernels(root / spec.file, source)
    colours = 3 if manifest.bayer is not None else 1
    if kernels.ndim != 6 or kernels.shape[:2] != (4, colours) or kernels.shape[4:] != (15, 15):
        raise InputFormatError(
            f"{root / spec.file}: shape {kernels.shape}; allowed: (4, {colours}, ky, kx, 15, 15)"
        )
    with tifffile.TiffFile(root / manifest.cameras[camera].file) as tif:
        frame = tuple(int(v) for v in tif.pages[0].shape[:2])
    colour = colours - 1  # green of R, B, G; the one colour of mono
    ky, kx = kernels.shape[2:4]
    target = spec.target_sigma_px
    psfs = [
        [psf_from_kernel(kernels[camera, colour, iy, ix], target) for ix in range(kx)]
        for iy in range(ky)
    ]
    return QuadPsfs(psfs=psfs, step=spec.step, frame=(frame[0], frame[1]))
