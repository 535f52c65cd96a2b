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

A burst need not be the quad's whole image: each frame's TIFF metadata (as elphel-camd
writes it) gives its window on the sensor (``WOI_LEFT``, ``WOI_TOP``) and its flips
(``FLIPH``, ``FLIPV``), and the quad's images may carry theirs. The regions then take the
cells under the burst's window, and a PSF is mirrored where the two images are flipped
differently. A quad image without them is the whole sensor from its corner, unflipped;
a burst without them must be the quad's whole image.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tifffile
from numpy.typing import NDArray
from scipy.optimize import least_squares

from elphel_host.burst.io import Burst
from elphel_host.errors import InputFormatError
from elphel_host.mfsr.gaussian_psf import GaussianPsf
from elphel_host.mfsr.psf_spec import MAX_REGIONS, GivenGrid, GivenKernel
from elphel_host.recordings.frames import complete_tiff_metadata
from elphel_host.tp.io import MANIFEST, QuadManifest
from elphel_host.tp.kernel_file import load_kernels

F64 = NDArray[np.float64]

#: DFT size the kernels' spectra are taken at.
N_FFT = 64


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
class SensorWindow:
    """Where an image lies on the sensor: its window (origin, size) and its flips."""

    left: int
    top: int
    height: int
    width: int
    fliph: bool = False
    flipv: bool = False

    def to_sensor(self, y: float, x: float) -> tuple[float, float]:
        """Sensor coordinates of image point (y, x) (continuous: pixel i spans [i, i+1))."""
        return (
            self.top + (self.height - y if self.flipv else y),
            self.left + (self.width - x if self.fliph else x),
        )

    def from_sensor(self, y: float, x: float) -> tuple[float, float]:
        """Image coordinates of sensor point (y, x)."""
        y, x = y - self.top, x - self.left
        return (self.height - y if self.flipv else y), (self.width - x if self.fliph else x)

    def covers(self, other: SensorWindow) -> bool:
        """``other`` lies within this window on the sensor."""
        return (
            self.left <= other.left
            and self.top <= other.top
            and other.left + other.width <= self.left + self.width
            and other.top + other.height <= self.top + self.height
        )

    def describe(self) -> str:
        flips = [name for name, on in (("FLIPH", self.fliph), ("FLIPV", self.flipv)) if on]
        return f"{self.width}x{self.height} at ({self.left}, {self.top})" + (
            f" {'+'.join(flips)}" if flips else ""
        )


def image_window(path: str | Path, shape: tuple[int, ...]) -> SensorWindow | None:
    """Where an image of ``shape`` lies on the sensor, from its TIFF's JSON metadata.

    elphel-camd writes ``WOI_LEFT``, ``WOI_TOP``, ``FLIPH`` and ``FLIPV`` there (flips
    missing: none); None for an image without its window in its metadata.
    """
    meta = complete_tiff_metadata(Path(path)) or {}  # none, or not elphel-camd's JSON
    if "WOI_LEFT" not in meta or "WOI_TOP" not in meta:
        return None

    def number(key: str) -> int:
        value = meta.get(key, 0)
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise InputFormatError(
                f"{path}: metadata {key}={value!r}; allowed: a whole number >= 0"
            )
        return value

    return SensorWindow(
        left=number("WOI_LEFT"),
        top=number("WOI_TOP"),
        height=int(shape[0]),
        width=int(shape[1]),
        fliph=bool(number("FLIPH")),
        flipv=bool(number("FLIPV")),
    )


@dataclass(frozen=True)
class QuadPsfs:
    """A quad camera's PSFs per kernel cell, and where its images lie on the sensor."""

    psfs: list[list[GaussianPsf]]  # [ky][kx], on the quad's image; green's for Bayer
    step: int
    window: SensorWindow  # of the quad's images
    colour_psfs: tuple[list[list[GaussianPsf]], ...] | None = None  # R, G, B (Bayer)

    @property
    def frame(self) -> tuple[int, int]:
        """(height, width) of the quad's images."""
        return self.window.height, self.window.width

    def grid(
        self,
        scale: int,
        frame: SensorWindow | None = None,
        psfs: list[list[GaussianPsf]] | None = None,
    ) -> F64:
        """PSFs on the output grid per MFSR region of ``frame``, ``(rows, columns, h, w)``.

        ``frame``: where the burst's frames lie on the sensor (default: the quad's whole
        image). One region per kernel cell the frame spans, up to :data:`MAX_REGIONS` a
        side, each the PSF of the cell under its centre, mirrored where the frame and the
        quad's images are flipped differently; padded to one size. ``psfs``: the cells'
        PSFs (default ``self.psfs``).

        Raises
        ------
        ValueError
            The frame does not lie within the quad's images on the sensor.
        """
        quad = self.window
        frame = frame or quad
        if not quad.covers(frame):
            raise ValueError(
                f"the burst's frames ({frame.describe()} on the sensor) do not lie within "
                f"the quad's images ({quad.describe()}) the PSFs were calibrated on"
            )
        cells = psfs or self.psfs
        ky, kx = len(cells), len(cells[0])
        flip_y, flip_x = frame.flipv != quad.flipv, frame.fliph != quad.fliph

        def cell(y: float, x: float) -> tuple[int, int]:  # a point of the frame
            qy, qx = quad.from_sensor(*frame.to_sensor(y, x))
            return min(max(int(qy // self.step), 0), ky - 1), min(
                max(int(qx // self.step), 0), kx - 1
            )

        (y0, x0), (y1, x1) = cell(0.5, 0.5), cell(frame.height - 0.5, frame.width - 0.5)
        rows = min(abs(y1 - y0) + 1, MAX_REGIONS)
        cols = min(abs(x1 - x0) + 1, MAX_REGIONS)
        kernels = []
        for i in range(rows):
            row = []
            for j in range(cols):
                cy, cx = cell((i + 0.5) * frame.height / rows, (j + 0.5) * frame.width / cols)
                psf = cells[cy][cx].mirrored(flip_y=flip_y, flip_x=flip_x)
                row.append(psf.on_grid(scale))
            kernels.append(row)
        side = max(k.shape[0] for row in kernels for k in row)
        return np.stack([np.stack([_padded(k, side) for k in row]) for row in kernels])

    def grid_rgb(self, scale: int, frame: SensorWindow | None = None) -> F64 | None:
        """`grid` of each colour, ``(3, rows, columns, h, w)`` (R, G, B); None for mono."""
        if self.colour_psfs is None:
            return None
        grids = [self.grid(scale, frame, psfs) for psfs in self.colour_psfs]
        side = max(g.shape[-1] for g in grids)
        return np.stack([[[_padded(k, side) for k in row] for row in g] for g in grids])


def _padded(kernel: F64, side: int) -> F64:
    """``kernel`` (square, odd) centred in a ``side`` x ``side`` array of zeros."""
    m = (side - kernel.shape[0]) // 2
    out = np.zeros((side, side))
    out[m : m + kernel.shape[0], m : m + kernel.shape[1]] = kernel
    return out


def quad_psfs(quad_dir: str | Path, camera: int = 0) -> QuadPsfs:
    """The PSFs of ``camera`` recovered from a quad directory's kernel file.

    ``psfs`` are green's for Bayer kernels (colours R, B, G in the file), the colour MFSR
    estimates its PSF on, and ``colour_psfs`` each colour's.

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
    image = root / manifest.cameras[camera].file
    with tifffile.TiffFile(image) as tif:
        shape = tif.pages[0].shape
    ky, kx = kernels.shape[2:4]
    target = spec.target_sigma_px
    fitted = [  # per colour of the file: R, B, G; the one colour of mono
        [
            [psf_from_kernel(kernels[camera, colour, iy, ix], target) for ix in range(kx)]
            for iy in range(ky)
        ]
        for colour in range(colours)
    ]
    window = image_window(image, shape) or SensorWindow(0, 0, int(shape[0]), int(shape[1]))
    rgb = None if colours == 1 else (fitted[0], fitted[2], fitted[1])
    return QuadPsfs(psfs=fitted[-1], step=spec.step, window=window, colour_psfs=rgb)


def quad_psf(
    quad: QuadPsfs, scale: int, frame: SensorWindow | None = None
) -> GivenKernel | GivenGrid:
    """The quad's PSFs for frames lying at ``frame`` on the sensor (default: its images)."""
    try:
        grid = quad.grid(scale, frame)
        rgb = quad.grid_rgb(scale, frame)
    except ValueError as e:
        raise InputFormatError(str(e)) from e
    size = quad.frame if frame is None else (frame.height, frame.width)
    if grid.shape[:2] == (1, 1):
        one = None if rgb is None else rgb[:, 0, 0]
        return GivenKernel(grid[0, 0], rgb=one, frame=size)
    return GivenGrid(grid, rgb=rgb, frame=size)


def burst_psf(
    quad: QuadPsfs, burst_dir: str | Path, burst: Burst, scale: int
) -> GivenKernel | GivenGrid:
    """The quad's PSFs under a burst's window on the sensor (its first frame's metadata).

    A burst whose frames do not give their window is taken for the quad's whole image
    (frames of another size are refused when fused).
    """
    first = Path(burst_dir) / burst.infos[0].file
    return quad_psf(quad, scale, image_window(first, burst.frames.shape[1:]))
