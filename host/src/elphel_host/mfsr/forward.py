"""Forward-model reconstruction of a translated burst, solved exactly in the Fourier domain.

Model. Low-resolution (LR) frame k, aligned to the reference grid up to a fractional shift
``phi_k`` (LR px, |phi| <= 0.5), sees at pixel i the high-resolution (HR) image integrated
over the pixel's area::

    y_k[i] = (h * x)(S*i + c + S*phi_k) + noise,      c = (S - 1) / 2

where S is the scale, x the HR image on the grid ``cv2.resize`` uses (LR pixel i has its
centre at HR coordinate S*i + c), and h the pixel aperture (a box of ``aperture`` HR px,
optionally convolved with a Gaussian blur), evaluated between grid points by trigonometric
(band-limited) interpolation.

Why the Fourier domain: in the DFT, LR frequency v of frame k only sees the S*S HR
frequencies that alias onto it, ``u_j = v + j' n`` (j' one of S*S integer pairs). Every
frame's row in the least-squares system for that block is ``(1/S^2) H(u_j) exp(2 pi i u_j
t_k / N)``; its normal matrix is ``D G D / S^4`` with D = diag(H(u_j)) and G an S^2 x S^2
matrix that is the same for every v. So the regularised least-squares problem

    min_x  sum_k |y_k - A_k x|^2 + lam * |grad x|^2

splits into independent S^2 x S^2 Hermitian systems, one per LR frequency, solved by a
vectorised LDL^H (:mod:`elphel_host.mfsr.ldl`). Frames are accumulated one chunk at a time
into S^2 LR-size spectra, so memory grows with the output size, not with the number of
frames.

Robustness (:mod:`elphel_host.mfsr.refine`): Huber regression by pseudo-data. After a
solve, each frame's residual is computed; residuals beyond ``huber * sigma`` are clipped
(and pixels outside a frame's valid area are replaced by the prediction), the right-hand
side is corrected and the system solved again.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial

import numpy as np
from numpy.typing import NDArray

from elphel_host.mfsr.kernels import MAX_FRAMES, accumulate, packed_irfft2, packed_rfft2, place
from elphel_host.mfsr.ldl import solve_blocks
from elphel_host.parallel import parallel_map

F32 = NDArray[np.float32]
C64 = NDArray[np.complex64]
F64 = NDArray[np.float64]

# A frame source: index -> (aligned LR frame float32, validity mask bool or None)
FrameSource = Callable[[int], tuple[F32, NDArray[np.bool_] | None]]

_CHUNK_FRAMES = MAX_FRAMES  # frames kernels.accumulate takes at once


_SOLVE_ROWS = 128
_BAND_ROWS = 64  # rows of the right-hand side a step of the accumulation takes
# Frames of fewer (padded) pixels take every step on one thread: the measuring windows'
# steps last well under a millisecond, less than handing them to other threads costs
# (measured: the 384 and 256 px windows 0.12 CPU s on one thread, 0.18 on two).
_SERIAL_PIXELS = 512 * 512


def threads_for(shape: tuple[int, int]) -> int | None:
    """Threads for the steps of a solve on frames of ``shape``: 1, or None (every core)."""
    return 1 if shape[0] * shape[1] < _SERIAL_PIXELS else None


@dataclass(frozen=True)
class ForwardModel:
    """Geometry and optics shared by every frame of one reconstruction.

    Parameters
    ----------
    lr_shape
        (rows, columns) of the (padded) LR frames.
    scale
        Integer up-sampling factor S.
    aperture
        Width of the pixel's box aperture in HR px (S for a full-fill mono sensor).
    blur_sigma
        Extra Gaussian blur of the optics in HR px (0 = none).
    kernel
        Optional PSF of the optics on the HR grid (2-D, odd sides, centred, sum 1); its
        centro-symmetric part is used (a real transfer function: an off-centre PSF only
        moves the image, which registration absorbs).
    prior_sigma
        Softness the prior expects of the HR image itself, as a Gaussian of this sigma
        (HR px): the gradient prior's weight at frequency f is multiplied by
        ``exp(4 pi^2 prior_sigma^2 |f|^2)`` (the prior is on the image sharpened by that
        Gaussian). It shapes the denoising only; nothing is deconvolved by it. 0: the
        plain gradient prior.
    """

    lr_shape: tuple[int, int]
    scale: int
    aperture: int
    blur_sigma: float = 0.0
    kernel: NDArray[np.float64] | None = field(default=None, compare=False)
    prior_sigma: float = 0.0

    @property
    def hr_shape(self) -> tuple[int, int]:
        return (self.lr_shape[0] * self.scale, self.lr_shape[1] * self.scale)

    def alias_offsets(self) -> list[tuple[int, int]]:
        """The integer pairs j' with HR frequency u = v + j' n, in a fixed order."""
        s = self.scale
        lo = -(s // 2)
        js = range(lo, lo + s)
        return [(jy, jx) for jy in js for jx in js]

    def lr_freq(self, axis: int) -> F64:
        """LR frequency representatives v (signed for odd S, unsigned for even S)."""
        n = self.lr_shape[axis]
        v = np.arange(n, dtype=np.float64)
        if self.scale % 2:
            v = np.where(v >= n / 2, v - n, v)
        return v


def _aperture_1d(u: F64, n_hr: int, aperture: int, blur_sigma: float) -> F64:
    """Transfer function of a centred box of ``aperture`` HR px (Dirichlet) times a Gaussian."""
    f = u / n_hr
    num = np.sin(np.pi * aperture * f)
    den = aperture * np.sin(np.pi * f)
    with np.errstate(invalid="ignore", divide="ignore"):
        h = np.where(np.abs(den) < 1e-12, 1.0, num / np.where(den == 0, 1.0, den))
    if blur_sigma > 0:
        h = h * np.exp(-2.0 * np.pi**2 * blur_sigma**2 * f**2)
    return np.asarray(h, dtype=np.float64)


class FourierSolver:
    """Accumulates frames and solves the regularised forward-model least squares.

    Parameters
    ----------
    model
        The shared geometry.
    shifts
        Per frame (dy, dx) fractional shift phi_k in LR px (frame k, pixel i sees the
        reference's LR coordinate i + phi_k).
    lam
        Weight of the gradient regulariser (about noise variance / gradient variance).
    """

    def __init__(
        self, model: ForwardModel, shifts: Sequence[tuple[float, float]], *, lam: float
    ) -> None:
        if lam <= 0:
            raise ValueError(f"lam={lam}; allowed: > 0")
        self.model = model
        self.threads = threads_for(model.lr_shape)
        s = model.scale
        ny, nx = model.lr_shape
        Ny, Nx = model.hr_shape
        self.offsets = model.alias_offsets()
        c = (s - 1) / 2.0
        # t_k: offset of frame k's sample positions on the HR grid (HR px)
        self.t = np.array([(c + s * dy, c + s * dx) for dy, dx in shifts], dtype=np.float64)
        self._jp = np.array(self.offsets, dtype=np.float64)  # (A, 2)
        self._update_coupling()
        vy, vx = model.lr_freq(0), model.lr_freq(1)
        # real frames: only LR x frequencies 0..nx/2 are kept (the rest are conjugates)
        self.nxh = nx // 2 + 1
        vx = vx[: self.nxh]
        self._vy, self._vx = vy, vx
        # per alias: 1-D transfer and 1-D regulariser factors per axis
        self.hy = {
            jy: _aperture_1d(vy + jy * ny, Ny, model.aperture, model.blur_sigma)
            for jy, _ in self.offsets
        }
        self.hx = {
            jx: _aperture_1d(vx + jx * nx, Nx, model.aperture, model.blur_sigma)
            for _, jx in self.offsets
        }
        self.ly = {jy: 4.0 * np.sin(np.pi * (vy + jy * ny) / Ny) ** 2 for jy, _ in self.offsets}
        self.lx = {jx: 4.0 * np.sin(np.pi * (vx + jx * nx) / Nx) ** 2 for _, jx in self.offsets}
        self.lam = lam
        self._factors: tuple[NDArray[np.float32], NDArray[np.float32]] | None = None
        self.rhs = np.zeros((len(self.offsets), ny, self.nxh), dtype=np.complex64)

    def _update_coupling(self) -> None:
        s = self.model.scale
        # C[k, j] = exp(-2 pi i j'.t_k / S): how frame k's spectrum feeds alias j
        self.C = np.exp(-2j * np.pi * (self.t @ self._jp.T) / s).astype(np.complex64)
        c128 = np.exp(-2j * np.pi * (self.t @ self._jp.T) / s)
        # G[j, j'] = sum_k C[k, j] conj(C[k, j']): the frame-independent normal matrix
        self.G = np.einsum("ka,kb->ab", c128, c128.conj())

    def move(self, k: int, dt_hr: tuple[float, float]) -> None:
        """Shift frame k's sample positions by ``dt_hr`` HR px (call before adding it)."""
        self.t[k] += np.asarray(dt_hr, dtype=np.float64)
        self._update_coupling()

    def reset(self, *, lam: float | None = None) -> None:
        """Clear the right-hand side (and optionally change the regularisation weight)."""
        self.rhs[...] = 0
        if lam is not None:
            self.lam = lam

    def shifts_lr(self) -> F64:
        """Current fractional shifts (dy, dx) in LR px."""
        s = self.model.scale
        return np.asarray((self.t - (s - 1) / 2.0) / s, dtype=np.float64)

    # -- frame spectra -------------------------------------------------------------------
    def ramps(self, k: int) -> tuple[C64, C64]:
        Ny, Nx = self.model.hr_shape
        ty, tx = self.t[k]
        ry = np.exp(-2j * np.pi * self._vy * ty / Ny).astype(np.complex64)
        rx = np.exp(-2j * np.pi * self._vx * tx / Nx).astype(np.complex64)
        return ry, rx

    def add_frames(
        self,
        ks: Sequence[int],
        frames: Sequence[F32],
        *,
        sign: float = 1.0,
        overwrite: bool = False,
    ) -> None:
        """Add (or with sign=-1 remove) frames' contributions to the right-hand side.

        ``overwrite``: the frames (float32, C-ordered) are transformed in place, and hold
        their spectra afterwards.
        """
        for start in range(0, len(ks), _CHUNK_FRAMES):
            idx = list(ks[start : start + _CHUNK_FRAMES])
            self._add_chunk(idx, frames[start : start + len(idx)], sign, overwrite)

    def _add_chunk(
        self, ks: list[int], frames: Sequence[F32], sign: float, overwrite: bool
    ) -> None:
        """rhs[a] += sign sum_k C[k, a] P_k: the FFTs a frame per core, one pass per band."""

        def spectrum(f: F32) -> F32:
            return packed_rfft2(f, out=f if overwrite else None)

        spectra = tuple(parallel_map(spectrum, list(frames), threads=self.threads))
        coef = (sign * self.C[ks]).astype(np.complex64)  # (k, A)
        ramps = [self.ramps(k) for k in ks]
        ry, rx = np.stack([r[0] for r in ramps]), np.stack([r[1] for r in ramps])

        ny = self.rhs.shape[1]

        def band(r0: int) -> None:
            accumulate(self.rhs, spectra, coef, ry, rx, first=r0, rows=min(_BAND_ROWS, ny - r0))

        bands = range(0, self.rhs.shape[1], _BAND_ROWS)
        parallel_map(band, bands, threads=self.threads)  # memory-bound

    # -- solve ---------------------------------------------------------------------------
    def block_factors(self) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """Per alias: aperture transfer D and gradient-prior weight L, (A, ny, nxh) each.

        Both are outer products of per-axis factors, formed in place in float32.
        """
        if self._factors is None:
            ny, nxh = self.rhs.shape[1:]
            d = np.empty((len(self.offsets), ny, nxh), np.float32)
            l2 = np.empty_like(d)
            py, px = self._prior_shape()
            f32 = partial(np.asarray, dtype=np.float32)

            def alias(a: int) -> None:
                jy, jx = self.offsets[a]
                np.multiply(f32(self.hy[jy])[:, None], f32(self.hx[jx])[None, :], out=d[a])
                np.add(f32(self.ly[jy])[:, None], f32(self.lx[jx])[None, :], out=l2[a])
                if py:
                    l2[a] *= f32(py[jy])[:, None]
                    l2[a] *= f32(px[jx])[None, :]

            parallel_map(alias, range(len(self.offsets)), threads=self.threads)
            if self.model.kernel is not None:
                d *= self._kernel_transfer().astype(np.float32)
            self._factors = (d, l2)
        return self._factors

    def _prior_shape(self) -> tuple[dict[int, F64], dict[int, F64]]:
        """exp(4 pi^2 prior_sigma^2 f^2) per axis and alias ({} without prior_sigma).

        Their outer product is the prior's weight at 2-D frequency (fy, fx); each factor
        is capped at e^30 (float32 stays finite; such frequencies are all prior anyway).
        """
        if self.model.prior_sigma <= 0:
            return {}, {}
        ny, nx = self.model.lr_shape
        Ny, Nx = self.model.hr_shape
        c = 4.0 * np.pi**2 * self.model.prior_sigma**2

        def axis(v: F64, n: int, n_hr: int, j: int) -> F64:
            return np.exp(np.minimum(c * ((v + j * n) / n_hr) ** 2, 30.0))

        py = {jy: axis(self._vy, ny, Ny, jy) for jy, _ in self.offsets}
        px = {jx: axis(self._vx, nx, Nx, jx) for _, jx in self.offsets}
        return py, px

    def _kernel_transfer(self) -> F64:
        """Real transfer of the model's kernel at every alias frequency, (A, ny, nxh)."""
        k = np.asarray(self.model.kernel, dtype=np.float64)
        ny, nx = self.model.lr_shape
        Ny, Nx = self.model.hr_shape
        ry, rx = (k.shape[0] - 1) // 2, (k.shape[1] - 1) // 2
        dy, dx = np.arange(-ry, ry + 1), np.arange(-rx, rx + 1)
        out = []
        for jy, jx in self.offsets:
            fy = (self._vy + jy * ny) / Ny
            fx = (self._vx + jx * nx) / Nx
            cy, sy = np.cos(2 * np.pi * np.outer(fy, dy)), np.sin(2 * np.pi * np.outer(fy, dy))
            cx, sx = np.cos(2 * np.pi * np.outer(fx, dx)), np.sin(2 * np.pi * np.outer(fx, dx))
            # Re sum k(d) exp(-2 pi i f.d): the centro-symmetric part's transfer
            out.append(cy @ k @ cx.T - sy @ k @ sx.T)
        return np.asarray(np.stack(out), dtype=np.float64)

    def solve(self) -> C64:
        """Solve every block; returns X_j(v), shape (A, ny, nxh), the HR spectrum by alias."""
        return solve_joint([self])[0]

    def _shifted(self, x: C64, jy: int, jx: int, shift_hr: tuple[float, float]) -> C64:
        """Alias (jy, jx)'s block resampled by ``shift_hr`` HR px (itself when zero)."""
        if shift_hr == (0.0, 0.0):
            return x
        ny, nx = self.model.lr_shape
        Ny, Nx = self.model.hr_shape
        py = np.exp(2j * np.pi * (self._vy + jy * ny) * shift_hr[0] / Ny).astype(np.complex64)
        px = np.exp(2j * np.pi * (self._vx + jx * nx) * shift_hr[1] / Nx).astype(np.complex64)
        out = x * py[:, None]
        out *= px[None, :]
        return out

    def to_image(
        self, X: C64, *, shift_hr: tuple[float, float] = (0.0, 0.0), out: F32 | None = None
    ) -> F32:
        """Place the alias blocks into the HR half-spectrum and return the real HR image.

        ``shift_hr`` (dy, dx) resamples the result exactly (band-limited) so that output
        pixel u shows the solution at u + shift. ``out``: C-ordered float32 of at least
        the HR image's size, whose memory the spectrum and the image take (the image is
        a view of it).
        """
        ny, nx = self.model.lr_shape
        Ny, Nx = self.model.hr_shape
        Nxh = Nx // 2 + 1
        if out is None:
            spec = np.zeros((Ny, Nx), dtype=np.float32)  # packed (kernels.packed_rfft2)
        elif out.dtype != np.float32 or not out.flags.c_contiguous or out.size < Ny * Nx:
            raise ValueError(
                f"out {out.dtype} of {out.size}; allowed: C-ordered float32 >= {Ny * Nx}"
            )
        else:
            spec = out.reshape(-1)[: Ny * Nx].reshape(Ny, Nx)
            spec[...] = 0
        blocks = [self._shifted(X[a], jy, jx, shift_hr) for a, (jy, jx) in enumerate(self.offsets)]
        # the conjugate half first, then the solved half (which wins where they meet)
        for direct in (False, True):
            sign = 1 if direct else -1
            for block, (jy, jx) in zip(blocks, self.offsets, strict=True):
                iy = ((sign * (self._vy + jy * ny)) % Ny).astype(np.int64)
                ix = ((sign * (self._vx + jx * nx)) % Nx).astype(np.int64)
                ix[ix >= Nxh] = -1
                if ix.max() >= 0:
                    place(spec, np.ascontiguousarray(block), iy, ix, not direct)
        return packed_irfft2(spec)


def solve_joint(solvers: Sequence[FourierSolver], *, out: C64 | None = None) -> C64:
    """Solve the blocks of several solvers of one shape and scale in one batched pass.

    The solvers (a Bayer burst's colour planes, each with its own frames, shifts,
    optics and prior weight) share the LR shape and the scale, so their block systems
    stack along a batch axis and are factored together (:func:`solve_blocks`). ``out``
    (complex64, C-ordered, the shape returned) receives the solutions.

    Returns
    -------
    C64
        (P, A, ny, nxh): each solver's :meth:`FourierSolver.solve`.
    """
    first = solvers[0]
    for other in solvers[1:]:
        if (other.model.lr_shape, other.model.scale) != (first.model.lr_shape, first.model.scale):
            raise ValueError(
                f"solver of {other.model.lr_shape} at x{other.model.scale}; allowed: the "
                f"first's {first.model.lr_shape} at x{first.model.scale}"
            )
    ny = first.model.lr_shape[0]
    s2 = np.float32(first.model.scale**2)
    factors = [s.block_factors() for s in solvers]
    # one factor array for all when the optics agree (the usual case): no copies
    same = all(f[0] is factors[0][0] or np.array_equal(f[0], factors[0][0]) for f in factors)
    same = same and all(np.array_equal(f[1], factors[0][1]) for f in factors)
    # (A, P or 1, ny, nxh): the batch axis second, as in the stacked right-hand sides
    d_all = factors[0][0][:, None] if same else np.stack([f[0] for f in factors], axis=1)
    l_all = factors[0][1][:, None] if same else np.stack([f[1] for f in factors], axis=1)
    p = len(solvers)
    g = np.stack([s.G for s in solvers], axis=-1).astype(np.complex64)[..., None, None]
    weight = np.array([s.lam for s in solvers], np.float32) * s2
    rhs = first.rhs[:, None] if p == 1 else np.stack([s.rhs for s in solvers], axis=1)
    # each solver's solution C-ordered (the kernels that read it need that)
    shape = (p, rhs.shape[0], *rhs.shape[2:])
    solutions = np.empty(shape, np.complex64) if out is None else out
    if solutions.shape != shape or not solutions.flags.c_contiguous:
        raise ValueError(f"out of shape {solutions.shape}; allowed: C-ordered {shape}")
    by_alias = np.moveaxis(solutions, 0, 1)

    # single precision is enough: the prior keeps every block well conditioned
    def rows(r0: int) -> None:
        r1 = min(ny, r0 + _SOLVE_ROWS)
        band = (d_all[:, :, r0:r1], g, l_all[:, :, r0:r1], rhs[:, :, r0:r1])
        solve_blocks(*band, weight=weight, scale=float(s2), out=by_alias[:, :, r0:r1])

    parallel_map(rows, range(0, ny, _SOLVE_ROWS), threads=first.threads)  # row bands
    return solutions
