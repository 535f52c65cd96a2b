"""The tile processor's input in memory: four images of one quad, checked at the door."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from elphel_host.errors import InputFormatError
from elphel_host.tp.clt import tile_grid
from elphel_host.tp.geometry import QuadGeometry

F32 = NDArray[np.float32]


@dataclass(frozen=True)
class QuadImages:
    """Four simultaneous images of one quad, scaled to full scale 1.0.

    Attributes
    ----------
    images
        ``(4, H, W)`` float32, H and W multiples of 8 (even for Bayer).
    bayer
        Pattern name or None for mono.
    geometry
        Camera positions and pairs (and, for a calibrated quad, its calibration, which
        must be for images of this size).
    kernels
        Optional aberration-correction kernels ``(4, colours, ky, kx, 15, 15)``
        (pixel domain, convolution): a grid at ``kernel_step`` pixels, kernel (kx, ky)
        centred at ``((kx + 0.5) * step, (ky + 0.5) * step)``; a 1 x 1 grid is one
        kernel for the whole sensor.
    kernel_step
        Grid step of ``kernels`` in pixels.
    """

    images: F32
    bayer: str | None = None
    geometry: QuadGeometry = field(default_factory=QuadGeometry)
    kernels: NDArray[np.floating] | None = None
    kernel_step: int = 16

    def __post_init__(self) -> None:
        a = self.images
        if a.ndim != 3 or a.shape[0] != 4:
            raise InputFormatError(f"images must have shape (4, H, W), got {a.shape}")
        if a.dtype != np.float32:
            raise InputFormatError(f"images must be float32, got {a.dtype}")
        tile_grid(a.shape[1], a.shape[2])
        cal = self.geometry.calibration
        if cal is not None and cal.image_size != (a.shape[2], a.shape[1]):
            cw, ch = cal.image_size
            raise InputFormatError(
                f"the calibration is for {cw}x{ch} images, the images are "
                f"{a.shape[2]}x{a.shape[1]}; allowed: a calibration of these cameras at this size"
            )
        if self.kernels is not None:
            k = self.kernels
            ncol = 1 if self.bayer is None else 3
            if k.ndim != 6 or k.shape[:2] != (4, ncol) or k.shape[4:] != (15, 15):
                raise InputFormatError(
                    f"kernels must have shape (4, {ncol}, ky, kx, 15, 15), got {k.shape}"
                )
            if self.kernel_step < 1:
                raise InputFormatError(f"kernel_step={self.kernel_step}; allowed: >= 1")

    @property
    def tiles(self) -> tuple[int, int]:
        return tile_grid(self.images.shape[1], self.images.shape[2])
