"""From disparity (pixels) to depth and 3-D points (millimetres).

Two cameras one side of the square apart (``baseline_mm``) see a point at depth Z shifted
by ``D = f B / (Z p)`` pixels (f the focal length, p the pixel pitch), so
``Z = f B / (D p)``. The point seen at continuous pixel (x, y) of the virtual centre
camera (pixel i covers [i, i + 1), principal point at the image centre (W/2, H/2)) is
``((x - W/2) p Z / f, (y - H/2) p Z / f, Z)``: +x right, +y down, +z forward. Tile
(tx, ty) is centred at (8tx + 4, 8ty + 4). A quad up-sampled by S has pitch p / S and S
times the disparity, so the depth is the same; :meth:`DepthOptics.scaled` gives its optics.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elphel_host.errors import InputFormatError

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]


@dataclass(frozen=True)
class DepthOptics:
    """What turns disparity into depth: focal length, pixel pitch, the square's side."""

    focal_length_mm: float
    pixel_pitch_um: float
    baseline_mm: float

    def __post_init__(self) -> None:
        for name in ("focal_length_mm", "pixel_pitch_um", "baseline_mm"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and np.isfinite(value) and value > 0):
                raise InputFormatError(f"optics {name}={value!r}; allowed: a number > 0")

    @classmethod
    def from_optics(cls, optics: Mapping[str, Any] | None, *, source: str) -> DepthOptics:
        """From a quad.json ``optics`` object.

        It needs ``focal_length_mm``, ``pixel_pitch_um`` and ``baseline_mm``.
        """
        need = ("focal_length_mm", "pixel_pitch_um", "baseline_mm")
        missing = [k for k in need if optics is None or k not in optics]
        if missing:
            raise InputFormatError(
                f"{source}: optics lacks {', '.join(missing)}: depth needs the focal length, "
                'the pixel pitch and the baseline (the square\'s side) in quad.json "optics"'
            )
        assert optics is not None
        return cls(*(float(optics[k]) for k in need))

    @property
    def pitch_mm(self) -> float:
        return self.pixel_pitch_um / 1000.0

    @property
    def focal_length_px(self) -> float:
        return self.focal_length_mm / self.pitch_mm

    def scaled(self, scale: float) -> DepthOptics:
        """The optics of the same camera up-sampled by ``scale`` (pitch divided by it)."""
        return DepthOptics(self.focal_length_mm, self.pixel_pitch_um / scale, self.baseline_mm)

    def depth_mm(self, disparity_px: NDArray[np.floating]) -> F64:
        """``Z = f B / (D p)``; NaN where D <= 0 (at or beyond infinity)."""
        d = np.asarray(disparity_px, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            z = self.focal_length_px * self.baseline_mm / d
        out: F64 = np.where(d > 0, z, np.nan)
        return out

    def disparity_px(self, depth_mm: NDArray[np.floating]) -> F64:
        """``D = f B / (Z p)``."""
        z = np.asarray(depth_mm, dtype=np.float64)
        out: F64 = self.focal_length_px * self.baseline_mm / z
        return out

    def points_mm(
        self,
        x_px: NDArray[np.floating],
        y_px: NDArray[np.floating],
        depth_mm: NDArray[np.floating],
        *,
        image_size: tuple[int, int],
    ) -> F64:
        """3-D points ``(..., 3)`` seen at continuous pixels (x, y) at depths Z."""
        w, h = image_size
        z = np.asarray(depth_mm, dtype=np.float64)
        s = z / self.focal_length_px
        out: F64 = np.stack(
            [(np.asarray(x_px) - w / 2.0) * s, (np.asarray(y_px) - h / 2.0) * s, z], axis=-1
        )
        return out
