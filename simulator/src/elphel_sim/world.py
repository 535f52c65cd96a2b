"""The world: the scene, the rig and virtual time — the one source of truth for what is seen.

Coordinates are millimetres in a right-handed world frame. Cameras look along their own
+z with +x right and +y down on the sensor; a camera with the identity rotation looks along
world +z. The stage carriage moves along ``Rig.axis``; mounts marked ``on_stage`` move with
it, so the renderer sees exactly the carriage position the stage model holds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from elphel_sim.calib_board import BoardState

Vec3 = tuple[float, float, float]
FloatArray = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class Texture:
    """A periodic texture on a square grid, evaluated between samples by cubic splines.

    For sub-pixel exact rendering the content should be band-limited well below the grid's
    Nyquist frequency (`procedural` makes it so; `band_limit` filters an image array).

    Parameters
    ----------
    data
        2-D float array, one period of the texture; values are relative radiance (~0..1).
    period_mm
        Physical size of one period along each axis of the plane.
    """

    data: FloatArray
    period_mm: float

    def __post_init__(self) -> None:
        if self.data.ndim != 2 or self.data.shape[0] != self.data.shape[1]:
            raise ValueError(
                f"texture data must be a square 2-D array, got shape {self.data.shape}"
            )
        if not self.period_mm > 0:
            raise ValueError(f"period_mm={self.period_mm}; allowed: > 0")

    @property
    def size(self) -> int:
        return int(self.data.shape[0])

    @classmethod
    def procedural(
        cls,
        *,
        period_mm: float,
        seed: int,
        size: int = 1024,
        band: float = 0.25,
        mean: float = 0.5,
        contrast: float = 0.8,
        slope: float = 1.0,
    ) -> Texture:
        """A random band-limited texture with a natural-image (1/f^slope) spectrum.

        Parameters
        ----------
        period_mm
            Physical size of one period.
        seed
            Seed of the random phases and amplitudes.
        size
            Grid samples per period along each axis.
        band
            Highest frequency as a fraction of the grid's Nyquist frequency (<= 0.5 keeps
            spline evaluation exact to ~1e-4).
        mean, contrast
            The result spans exactly ``mean +- contrast/2`` (linear scaling, no clipping,
            so the texture stays band-limited).
        slope
            Exponent of the amplitude fall-off with frequency.
        """
        if not 0 < band <= 1:
            raise ValueError(f"band={band}; allowed: 0 < band <= 1")
        rng = np.random.default_rng(seed)
        f = np.fft.fftfreq(size)
        fx, fy = np.meshgrid(f, f)
        radius = np.hypot(fx, fy)
        cutoff = 0.5 * band
        amplitude = np.where(
            (radius > 0) & (radius <= cutoff), 1.0 / np.maximum(radius, 1.0 / size) ** slope, 0.0
        )
        spectrum = amplitude * np.exp(2j * np.pi * rng.random((size, size)))
        data = np.fft.ifft2(spectrum).real
        data -= data.min()
        data *= contrast / data.max()
        data += mean - contrast / 2
        return cls(data=data, period_mm=period_mm)

    @classmethod
    def from_image(
        cls, image: NDArray[np.generic], *, period_mm: float, band: float = 0.5
    ) -> Texture:
        """A texture from an image array (square or cropped to square), band-limited.

        The image is treated as one period; content above ``band`` x Nyquist is removed
        so that evaluation between samples stays exact.
        """
        a = np.asarray(image, dtype=np.float64)
        if a.ndim == 3:
            a = a.mean(axis=2)
        if a.ndim != 2:
            raise ValueError(f"image must be 2-D or 3-D (colour), got shape {a.shape}")
        n = min(a.shape)
        a = a[:n, :n]
        peak = a.max()
        if peak > 0:
            a = a / peak
        return cls(data=band_limit(a, band=band), period_mm=period_mm)


def band_limit(data: FloatArray, *, band: float) -> FloatArray:
    """Remove frequencies above ``band`` x Nyquist from a periodic 2-D array."""
    f = np.fft.fftfreq(data.shape[0])
    g = np.fft.fftfreq(data.shape[1])
    keep = np.hypot(*np.meshgrid(g, f)) <= 0.5 * band
    out: FloatArray = np.fft.ifft2(np.fft.fft2(data) * keep).real
    return out


def _unit(v: Sequence[float], name: str) -> FloatArray:
    a = np.asarray(v, dtype=np.float64)
    n = float(np.linalg.norm(a))
    if a.shape != (3,) or n == 0:
        raise ValueError(f"{name}={tuple(v)}; allowed: a non-zero 3-vector")
    return a / n


@dataclass(frozen=True, eq=False)
class Plane:
    """A textured plane (or rectangle) in the world.

    Parameters
    ----------
    texture
        What is painted on it.
    origin
        A point of the plane (mm) where texture coordinates are (0, 0) at time 0.
    u_axis, v_axis
        Directions of the texture's x and y on the plane; made orthonormal.
    half_extent_mm
        Half sizes along u and v, or None for an infinite plane.
    albedo_rgb
        Per-colour reflectance multiplying the texture.
    velocity_mm_s
        Constant velocity of the plane (moving objects for photo-finish).
    """

    texture: Texture
    origin: Vec3 = (0.0, 0.0, 1000.0)
    u_axis: Vec3 = (1.0, 0.0, 0.0)
    v_axis: Vec3 = (0.0, 1.0, 0.0)
    half_extent_mm: tuple[float, float] | None = None
    albedo_rgb: Vec3 = (1.0, 1.0, 1.0)
    velocity_mm_s: Vec3 = (0.0, 0.0, 0.0)

    def basis(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Orthonormal (u, v, normal) of the plane."""
        u = _unit(self.u_axis, "u_axis")
        v = _unit(self.v_axis, "v_axis")
        v = v - u * float(u @ v)
        v = _unit(tuple(v), "v_axis (orthogonalised)")
        return u, v, np.cross(u, v)


@dataclass
class Scene:
    """Everything there is to see: planes in front of a uniform background."""

    planes: list[Plane] = field(default_factory=list)
    background: float = 0.0


@dataclass(frozen=True)
class CameraMount:
    """Where a camera sits: relative to the stage carriage (``on_stage``) or to the world.

    ``rotation`` is the 3x3 world-from-camera rotation (columns are the camera's x, y, z
    axes in world coordinates); None means the identity (looking along world +z).
    """

    name: str
    offset_mm: Vec3 = (0.0, 0.0, 0.0)
    rotation: tuple[Vec3, Vec3, Vec3] | None = None
    on_stage: bool = True


@dataclass(frozen=True)
class Pose:
    """A camera's position (mm) and world-from-camera rotation in the world."""

    position_mm: FloatArray
    rotation: FloatArray

    @classmethod
    def at(
        cls, position_mm: Sequence[float] | FloatArray, rotation: FloatArray | None = None
    ) -> Pose:
        r = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
        if r.shape != (3, 3) or not np.allclose(r.T @ r, np.eye(3), atol=1e-9):
            raise ValueError("rotation must be a 3x3 orthonormal matrix")
        return cls(np.asarray(position_mm, dtype=np.float64), r)


@dataclass
class Rig:
    """The stage carriage and the camera mounts.

    ``carriage_mm`` is the true carriage position along ``axis``; the stage simulator keeps
    it up to date.
    """

    axis: Vec3 = (1.0, 0.0, 0.0)
    carriage_mm: float = 0.0
    mounts: dict[str, CameraMount] = field(default_factory=dict)


@dataclass
class World:
    """The scene, the rig and virtual time.

    ``board`` is a printed calibration board in view (`elphel_sim.calib_board`), or None.
    """

    scene: Scene
    rig: Rig = field(default_factory=Rig)
    time_s: float = 0.0
    board: BoardState | None = None

    def camera_pose(self, mount: str | CameraMount) -> Pose:
        """Pose of a mounted camera now, following the carriage if the mount is on it."""
        m = self.rig.mounts[mount] if isinstance(mount, str) else mount
        position = np.asarray(m.offset_mm, dtype=np.float64)
        if m.on_stage:
            position = position + self.rig.carriage_mm * _unit(self.rig.axis, "rig.axis")
        rotation = None if m.rotation is None else np.asarray(m.rotation, dtype=np.float64).T
        return Pose.at(position, rotation)
