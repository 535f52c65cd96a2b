"""The one Gaussian point-spread function of the project: host MFSR and the simulator.

A Gaussian PSF is a covariance (2x2, rows/columns ordered (y, x)) and a centre offset, in
the pixels of whatever grid it is stated on: the lens of a simulated sensor, a calibrated
quad's kernel cell, or a blur given to the MFSR reconstruction on its output grid.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

#: Largest kernel side (px) a PSF is drawn on.
MAX_KERNEL = 31


@dataclass(frozen=True)
class GaussianPsf:
    """An elliptical Gaussian PSF: covariance ``cov`` (px^2, (y, x)) and centre ``offset``.

    Build a round one with :meth:`round`; ``sigma_px`` is its standard deviation when it
    is round and centred.
    """

    cov: F64 = field(compare=False)
    offset: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        c = np.asarray(self.cov, dtype=np.float64)
        if c.shape != (2, 2) or not np.all(np.isfinite(c)) or not np.allclose(c, c.T):
            raise ValueError(f"cov of shape {c.shape}; allowed: a finite symmetric 2x2 array")
        if np.linalg.eigvalsh(c)[0] < 0:
            raise ValueError(f"cov {c.tolist()}; allowed: positive semi-definite")
        object.__setattr__(self, "cov", c)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, GaussianPsf):
            return NotImplemented
        return bool(np.array_equal(self.cov, other.cov)) and self.offset == other.offset

    def __hash__(self) -> int:
        return hash((tuple(self.cov.ravel()), self.offset))

    @classmethod
    def round(cls, sigma_px: float) -> GaussianPsf:
        """A centred, rotationally symmetric PSF of standard deviation ``sigma_px``."""
        if not sigma_px >= 0:
            raise ValueError(f"sigma_px={sigma_px}; allowed: >= 0")
        return cls(cov=np.eye(2) * float(sigma_px) ** 2)

    @property
    def sigma_px(self) -> float | None:
        """The standard deviation of a round, centred PSF; None for any other."""
        c = self.cov
        if self.offset != (0.0, 0.0) or c[0, 1] != 0 or c[0, 0] != c[1, 1]:
            return None
        return float(np.sqrt(c[0, 0]))

    @property
    def sigmas(self) -> tuple[float, float]:
        """Standard deviations along the principal axes, larger first."""
        ev = np.linalg.eigvalsh(self.cov)
        return float(np.sqrt(max(ev[1], 0.0))), float(np.sqrt(max(ev[0], 0.0)))

    def mirrored(self, *, flip_y: bool, flip_x: bool) -> GaussianPsf:
        """The PSF as seen in an image mirrored top-bottom (``flip_y``) and/or left-right."""
        sy, sx = (-1.0 if flip_y else 1.0), (-1.0 if flip_x else 1.0)
        m = np.diag([sy, sx])
        return replace(
            self, cov=m @ self.cov @ m, offset=(sy * self.offset[0], sx * self.offset[1])
        )

    def scaled(self, factor: float) -> GaussianPsf:
        """The same PSF on a grid ``factor`` times finer."""
        f = float(factor)
        return GaussianPsf(cov=self.cov * f * f, offset=(self.offset[0] * f, self.offset[1] * f))

    def on_grid(self, scale: int) -> F64:
        """The PSF on a grid ``scale`` times finer, sum 1, odd sides up to :data:`MAX_KERNEL`."""
        g = self.scaled(scale)
        oy, ox = g.offset
        reach = 3.0 * g.sigmas[0] + max(abs(oy), abs(ox))
        half = int(min(np.ceil(reach), MAX_KERNEL // 2))
        y, x = np.mgrid[-half : half + 1, -half : half + 1].astype(np.float64)
        d = np.stack([y - oy, x - ox], axis=-1)
        q = np.einsum("...i,ij,...j->...", d, np.linalg.inv(g.cov), d)
        k = np.exp(-0.5 * q)
        return np.asarray(k / k.sum(), dtype=np.float64)
