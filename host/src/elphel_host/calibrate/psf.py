"""Each camera's point-spread function over its field, from the checkerboard's edges.

Every edge between two neighbouring corners of a found board is an edge-spread function
(ESF): across the edge, the pixels' values follow ``m + a * erf(d / (sqrt(2) s))`` with
``d`` the pixel centre's signed distance to the edge. The middle half of each edge is
used (the neighbouring edges stay out of it) and ``s`` is fitted with the edge's offset,
level and contrast. A pixel integrates a unit square, which adds 1/12 px^2 to the
variance across any edge (the square's projection on any direction has that variance),
so the lens's Gaussian sigma there is ``sqrt(s^2 - 1/12)``.

The sigmas of all views are then fitted by a smooth field over the image, a quadratic
polynomial in x and y (robustly: edges farther than 4 spreads out are left out), and
read at the centre of each cell of a grid ``step`` pixels wide: the cells of the tile
processor's kernel file and the regions of the PSF grid ``elphel mfsr --psf`` takes.
A Bayer frame is measured as one grey image (`detect.grey_image`), so each colour gets
the same PSF.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.special import erf

from elphel_host import strict_json
from elphel_host.calibrate.detect import detect, grey_image
from elphel_host.calibrate.pattern import Checkerboard
from elphel_host.calibrate.views import view_images, view_sources
from elphel_host.errors import ElphelError
from elphel_host.fileio import write_atomic
from elphel_host.mfsr.gaussian_psf import GaussianPsf
from elphel_host.mfsr.psf_spec import MAX_REGIONS
from elphel_host.tp.kernel_file import MAX_TARGET_SIGMA_PX, KernelFile

FloatArray = NDArray[np.float64]
PIXEL_VARIANCE = 1.0 / 12.0
#: Side of the tile processor's kernels (px).
KERNEL_SIDE = 15
#: Fewest edges a camera needs for its field.
MIN_EDGES = 30


class PsfMeasurementError(ElphelError, ValueError):
    """Too few edges to measure a camera's PSF; the message says what to add."""


def _edge_pixels(
    grey: FloatArray, p0: FloatArray, p1: FloatArray, half_width: float
) -> tuple[FloatArray, FloatArray]:
    """Signed distances to the edge p0-p1 and values of the pixels along its middle half."""
    length = float(np.hypot(*(p1 - p0)))
    along = (p1 - p0) / length
    normal = np.array([-along[1], along[0]])
    lo = np.floor(np.minimum(p0, p1) - half_width - 1).astype(int)
    hi = np.ceil(np.maximum(p0, p1) + half_width + 1).astype(int)
    h, w = grey.shape
    lo, hi = np.maximum(lo, 0), np.minimum(hi, [w - 1, h - 1])
    ys, xs = np.mgrid[lo[1] : hi[1] + 1, lo[0] : hi[0] + 1]
    rel = np.stack([xs.ravel() - p0[0], ys.ravel() - p0[1]], axis=-1).astype(np.float64)
    t, d = rel @ along, rel @ normal
    keep = (t > 0.25 * length) & (t < 0.75 * length) & (np.abs(d) <= half_width)
    return d[keep], grey[ys.ravel()[keep], xs.ravel()[keep]]


def fit_edge(d: FloatArray, values: FloatArray) -> float:
    """The ESF's width ``s`` (px, pixel area included) of samples across one edge; NaN if none."""
    if len(d) < 12:
        return float("nan")
    lo, hi = np.percentile(values, (5, 95))
    sign = 1.0 if np.mean(values[d > 0]) > np.mean(values[d < 0]) else -1.0
    start = np.array([(lo + hi) / 2, sign * (hi - lo) / 2, 1.0, 0.0])

    def residual(p: FloatArray) -> FloatArray:
        out: FloatArray = p[0] + p[1] * erf((d - p[3]) / (np.sqrt(2) * p[2])) - values
        return out

    bounds = ([-np.inf, -np.inf, 0.2, -2.0], [np.inf, np.inf, 6.0, 2.0])
    fit = least_squares(residual, start, bounds=bounds)
    return float(fit.x[2]) if fit.success else float("nan")


def edge_widths(grey: FloatArray, corners: FloatArray, pattern: Checkerboard) -> FloatArray:
    """Per edge between neighbouring corners: its middle ``(x, y)`` and lens sigma (px).

    Returns ``(N, 3)``; edges whose fit failed are left out.
    """
    grid = corners.reshape(pattern.rows, pattern.cols, 2)
    pairs = [(grid[:, :-1], grid[:, 1:]), (grid[:-1, :], grid[1:, :])]
    out = []
    for a, b in pairs:
        for p0, p1 in zip(a.reshape(-1, 2), b.reshape(-1, 2), strict=True):
            if not (np.all(np.isfinite(p0)) and np.all(np.isfinite(p1))):
                continue
            half = min(6.0, 0.3 * float(np.hypot(*(p1 - p0))))
            s = fit_edge(*_edge_pixels(grey, p0, p1, half))
            if np.isfinite(s) and s * s > PIXEL_VARIANCE:
                mid = 0.5 * (p0 + p1)
                out.append((mid[0], mid[1], np.sqrt(s * s - PIXEL_VARIANCE)))
    return np.asarray(out, dtype=np.float64).reshape(-1, 3)


def _basis(x: FloatArray, y: FloatArray, size: tuple[int, int]) -> FloatArray:
    u, v = 2 * x / size[0] - 1, 2 * y / size[1] - 1
    return np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=-1)


def fit_field(edges: FloatArray, size: tuple[int, int]) -> tuple[FloatArray, int]:
    """Quadratic field of the sigma over the image: its 6 coefficients and edges used."""
    keep = np.ones(len(edges), dtype=bool)
    a = _basis(edges[:, 0], edges[:, 1], size)
    coef = np.zeros(6)
    for _ in range(4):
        coef = np.linalg.lstsq(a[keep], edges[keep, 2], rcond=None)[0]
        r = edges[:, 2] - a @ coef
        spread = 1.4826 * float(np.median(np.abs(r[keep]))) + 1e-6
        keep = np.abs(r) <= 4 * spread
    return coef, int(keep.sum())


@dataclass(frozen=True)
class PsfField:
    """A camera's lens sigma (sensor px) per grid cell, from its edges' field."""

    size: tuple[int, int]
    step: int
    coefficients: FloatArray
    sigma_px: FloatArray  # (ky, kx) at the cells' centres
    edges: NDArray[np.int64]  # (ky, kx) edges measured in each cell
    used: int

    def sigma_at(self, x: FloatArray, y: FloatArray) -> FloatArray:
        out: FloatArray = _basis(np.asarray(x, float), np.asarray(y, float), self.size) @ (
            self.coefficients
        )
        return out


def check_psf_options(cells: int, scale: int, target_sigma_px: float) -> None:
    """Refuse options the files cannot hold; ValueError names the option and what is allowed."""
    if not 1 <= cells <= MAX_REGIONS:
        raise ValueError(f"--cells {cells}; allowed: 1..{MAX_REGIONS}")
    if not 1 <= scale <= 8:
        raise ValueError(f"--scale {scale}; allowed: 1..8")
    if not 0 < target_sigma_px <= MAX_TARGET_SIGMA_PX:
        raise ValueError(
            f"--target-sigma-px {target_sigma_px:g}; allowed: > 0 and <= {MAX_TARGET_SIGMA_PX:g}"
        )


def grid_step(size: tuple[int, int], cells: int) -> int:
    """A cell side (multiple of 8) that covers the image with at most ``cells`` a side."""
    return int(np.ceil(max(size) / cells / 8) * 8)


def psf_field(edges: FloatArray, size: tuple[int, int], step: int) -> PsfField:
    """The field of ``edges`` (`edge_widths` of every view) read on cells ``step`` wide."""
    if len(edges) < MIN_EDGES:
        raise PsfMeasurementError(
            f"{len(edges)} edges measured; allowed: at least {MIN_EDGES}: add views where "
            "the whole board is seen sharp"
        )
    coef, used = fit_field(edges, size)
    kx, ky = -(-size[0] // step), -(-size[1] // step)
    cy, cx = np.mgrid[0:ky, 0:kx]
    xs = np.minimum((cx + 0.5) * step, size[0] - 1)
    ys = np.minimum((cy + 0.5) * step, size[1] - 1)
    count = np.zeros((ky, kx), dtype=np.int64)
    ix = np.clip((edges[:, 0] // step).astype(int), 0, kx - 1)
    iy = np.clip((edges[:, 1] // step).astype(int), 0, ky - 1)
    np.add.at(count, (iy, ix), 1)
    sigma = _basis(xs.astype(float), ys.astype(float), size) @ coef
    return PsfField(size, step, coef, np.maximum(sigma, 0.05), count, used)


def measure_psfs(
    root: str | Path, pattern: Checkerboard, *, cells: int = 4
) -> tuple[list[PsfField], str | None]:
    """Each camera's `PsfField` from a views directory, and the views' Bayer pattern.

    ``cells``: the grid's cells along the image's longer side.
    """
    if not 1 <= cells <= MAX_REGIONS:
        raise ValueError(f"cells={cells}; allowed: 1..{MAX_REGIONS}")
    sources, quad = view_sources(Path(root))
    per_camera: list[list[FloatArray]] = []
    size, bayer = (0, 0), None
    for path in sources:
        images, bayer = view_images(path, quad=quad)
        per_camera += [[] for _ in range(len(images) - len(per_camera))]
        for cam, image in enumerate(images):
            size = (int(image.shape[1]), int(image.shape[0]))
            found = detect(np.asarray(image), pattern, bayer=bayer)
            if found is not None:
                grey = grey_image(np.asarray(image), bayer)
                per_camera[cam].append(edge_widths(grey, found.pixels, pattern))
    step = grid_step(size, cells)
    out = []
    for cam, sets in enumerate(per_camera):
        try:
            out.append(psf_field(np.concatenate([np.empty((0, 3)), *sets]), size, step))
        except PsfMeasurementError as e:
            raise PsfMeasurementError(f"camera {cam}: {e}") from e
    return out, bayer


def correction_kernels(
    fields: list[PsfField], *, colours: int, target_sigma_px: float, eps: float = 1e-3
) -> NDArray[np.float32]:
    """Kernels ``(cameras, colours, ky, kx, 15, 15)`` turning each cell's PSF into the target.

    A regularised inverse in the frequency domain: ``target * conj(P) / (|P|^2 + eps)``,
    cut to 15 x 15 and normalised to sum 1 (the tile processor's kernel file).
    """
    n = 64
    f = np.fft.fftfreq(n)
    fr2 = f[:, None] ** 2 + f[None, :] ** 2
    target = np.exp(-2 * np.pi**2 * target_sigma_px**2 * fr2)
    ky, kx = fields[0].sigma_px.shape
    out = np.empty((len(fields), colours, ky, kx, KERNEL_SIDE, KERNEL_SIDE), dtype=np.float32)
    half = KERNEL_SIDE // 2
    for cam, field in enumerate(fields):
        for iy, ix in np.ndindex(ky, kx):
            p = np.exp(-2 * np.pi**2 * float(field.sigma_px[iy, ix]) ** 2 * fr2)
            k = np.fft.ifft2(target * p / (p * p + eps)).real
            k = np.roll(k, (half, half), axis=(0, 1))[:KERNEL_SIDE, :KERNEL_SIDE]
            out[cam, :, iy, ix] = k / k.sum()
    return out


def psf_grid(field: PsfField, scale: int) -> FloatArray:
    """The PSF per cell drawn on a grid ``scale`` times finer: ``(ky, kx, n, n)``, sum 1 each."""
    kernels = [[GaussianPsf.round(float(s)).on_grid(scale) for s in row] for row in field.sigma_px]
    side = max(k.shape[0] for row in kernels for k in row)
    out = np.zeros((*field.sigma_px.shape, side, side))
    for iy, row in enumerate(kernels):
        for ix, k in enumerate(row):
            pad = (side - k.shape[0]) // 2
            out[iy, ix, pad : pad + k.shape[0], pad : pad + k.shape[1]] = k
    return out


def write_psfs(
    fields: list[PsfField],
    out_dir: str | Path,
    *,
    bayer: bool,
    scale: int,
    target_sigma_px: float,
) -> dict[str, Any]:
    """Write kernels.npy, psf_camN_xS.npy and psf.json into ``out_dir``; psf.json's content."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    kernels = correction_kernels(fields, colours=3 if bayer else 1, target_sigma_px=target_sigma_px)
    np.save(out / "kernels.npy", kernels)
    grids = []
    for cam, field in enumerate(fields):
        name = f"psf_cam{cam}_x{scale}.npy"
        np.save(out / name, psf_grid(field, scale))
        grids.append(name)
    doc = {
        "version": 1,
        "kernels": KernelFile("kernels.npy", fields[0].step, target_sigma_px).to_json(),
        "psf_grids": grids,
        "scale": scale,
        "cameras": [
            {
                "width": f.size[0],
                "height": f.size[1],
                "sigma_px": np.round(f.sigma_px, 4).tolist(),
                "edges": f.edges.tolist(),
                "edges_used": f.used,
                "field_coefficients": f.coefficients.tolist(),
            }
            for f in fields
        ],
    }
    write_atomic(
        out / "psf.json", (strict_json.dumps(doc, what="psf.json", indent=1) + "\n").encode()
    )
    return doc
