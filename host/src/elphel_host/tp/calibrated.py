"""Where each camera of a calibrated quad sees every tile, from its calibration.json.

A real quad's lenses distort differently, their sensors are turned by fractions of a
degree and their focal lengths differ by up to a percent: images taken as they are do not
follow the ideal geometry (``p - D * position``). With a calibration (docs/calibration.md)
the tile processor works in a *virtual centre camera* instead: a distortion-free pinhole
(the common model) looking along camera 0's axis from the centre of the four cameras,
with their mean focal length ``f`` and its principal point at the image centre. For a
tile centred at continuous pixel (x, y) of that camera and a disparity D, camera i's
pixel is found as Elphel's geometry correction does:

1. undistort with the common model: the ray ``((x - W/2) / f, (y - H/2) / f, 1)``;
2. shift by the disparity along the camera's direction: subtract ``D / (f B) * c_i``,
   where ``c_i`` is camera i's centre relative to the virtual camera's (mm) and ``B``
   the square's side (mm), so a point at depth Z (``D = f B / Z``) stays on its ray;
3. turn into camera i's frame (its rotation ``R_i``) and divide by the depth there;
4. distort with camera i's own lens (OpenCV's rational model, its own focal length and
   principal point).

The integer part of the result picks the tile's pixel window and the fraction becomes
the sub-pixel shift (a phase rotation), as for the ideal geometry
(:meth:`elphel_host.tp.geometry.QuadGeometry.place_camera`). Disparities, depths and
point clouds are then those of the virtual camera: ``Z = f B / D``.

The tile processor places its tiles through :meth:`CalibratedGeometry.place`, one
compiled loop per chunk of tiles and camera (:func:`elphel_host.tp.fused.lens_windows`)
that computes what :meth:`CalibratedGeometry.pixels` computes, bit for bit.

A camera's image moves by about ``J`` pixels per pixel of disparity, J the local scale of
its lens (below 1 towards the corners of a barrel-distorted image); the correlation
measures raw pixels, so :meth:`CalibratedGeometry.disparity_gain` gives per tile the
pixels the pairs' separations move per unit of disparity, by which the measured residuals
are divided.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from elphel_host.calibrate.camera_model import CameraModel, distort
from elphel_host.depth.geometry import DepthOptics
from elphel_host.errors import InputFormatError
from elphel_host.tp.geometry import TilePlacement, window_at

F64 = NDArray[np.float64]

#: The file a calibration directory holds (docs/calibration.md).
CALIBRATION_FILE = "calibration.json"
#: The four sides of the square: (0, 1), (2, 3), (0, 2), (1, 3).
SIDES = ((0, 1), (2, 3), (0, 2), (1, 3))


@dataclass(frozen=True, eq=False)
class CalibratedGeometry:
    """A calibrated quad seen from its virtual centre camera (module docstring).

    Attributes
    ----------
    lenses
        The four cameras' lenses (OpenCV's rational model, pixel (0, 0) at the centre of
        the first pixel).
    rotations
        ``(4, 3, 3)``: the virtual camera's (= camera 0's) frame into each camera's.
    offsets_mm
        ``(4, 3)``: each camera's centre relative to the virtual camera's, in its frame.
    focal_px
        The virtual camera's focal length (the lenses' mean).
    baseline_mm
        The square's side: the mean distance between neighbouring cameras.
    """

    lenses: tuple[CameraModel, ...]
    rotations: F64
    offsets_mm: F64
    focal_px: float
    baseline_mm: float

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of the images the calibration is for."""
        return self.lenses[0].width, self.lenses[0].height

    @classmethod
    def from_cameras(
        cls, cameras: Sequence[tuple[CameraModel, F64, F64]], *, source: str = "calibration"
    ) -> CalibratedGeometry:
        """From each camera's (lens, R, t_mm) as calibration.json has them (camera 0 first).

        Raises
        ------
        InputFormatError
            Not four cameras, cameras of different image sizes, or cameras that do not
            span a square (coincident centres).
        """
        if len(cameras) != 4:
            raise InputFormatError(f"{source}: {len(cameras)} cameras; allowed: 4 (a quad)")
        sizes = {(lens.width, lens.height) for lens, _, _ in cameras}
        if len(sizes) != 1:
            raise InputFormatError(
                f"{source}: cameras of different image sizes {sorted(sizes)}; allowed: one size"
            )
        r0 = np.asarray(cameras[0][1], dtype=np.float64)
        t0 = np.asarray(cameras[0][2], dtype=np.float64)
        rotations = np.stack([np.asarray(r, dtype=np.float64) @ r0.T for _, r, _ in cameras])
        # centres in camera 0's frame: X_i = R_i X_0 + t_i is zero at X_0 = -R_i^T t_i
        centres = np.stack(
            [r0 @ (-np.asarray(r, dtype=np.float64).T @ t) + t0 for _, r, t in cameras]
        )
        offsets = centres - centres.mean(axis=0)
        baseline = float(np.mean([np.linalg.norm(centres[a] - centres[b]) for a, b in SIDES]))
        if not (np.all(np.isfinite(offsets)) and baseline > 0):
            raise InputFormatError(
                f"{source}: the cameras' centres {centres.tolist()} span no square; "
                "allowed: four cameras at different places"
            )
        focal = float(np.mean([(lens.fx + lens.fy) / 2 for lens, _, _ in cameras]))
        return cls(tuple(lens for lens, _, _ in cameras), rotations, offsets, focal, baseline)

    def pixels(
        self,
        camera: int,
        cx: NDArray[np.floating],
        cy: NDArray[np.floating],
        disparity: NDArray[np.floating],
    ) -> tuple[F64, F64]:
        """Continuous pixel (x, y) in ``camera`` of what the virtual camera sees at (cx, cy).

        ``cx``, ``cy`` are continuous pixels of the virtual camera (pixel i covers
        [i, i + 1)), ``disparity`` its disparity there (broadcast with them).
        """
        w, h = self.image_size
        x = (np.asarray(cx, dtype=np.float64) - w / 2) / self.focal_px
        y = (np.asarray(cy, dtype=np.float64) - h / 2) / self.focal_px
        s = np.asarray(disparity, dtype=np.float64) / (self.focal_px * self.baseline_mm)
        o = self.offsets_mm[camera]
        ray = (x - s * o[0], y - s * o[1], 1.0 - s * o[2])
        r = self.rotations[camera]
        xc, yc, zc = (r[k, 0] * ray[0] + r[k, 1] * ray[1] + r[k, 2] * ray[2] for k in range(3))
        lens = self.lenses[camera]
        xd, yd = distort(xc / zc, yc / zc, lens.coefficients)
        px, py = lens.fx * xd + lens.cx, lens.fy * yd + lens.cy
        if lens.residual is not None:
            px, py = np.broadcast_arrays(px, py)
            moved = lens.residual.at(np.column_stack([px.ravel(), py.ravel()]))
            px, py = px + moved[:, 0].reshape(px.shape), py + moved[:, 1].reshape(py.shape)
        return px + 0.5, py + 0.5

    def lens_parameters(self, camera: int) -> F64:
        """``camera`` packed for the compiled :func:`elphel_host.tp.fused.lens_pixels`.

        The values named by :data:`elphel_host.tp.fused.LENS_PARAMETERS`, in that order.
        """
        w, h = self.image_size
        lens = self.lenses[camera]
        return np.concatenate(
            [
                [w / 2, h / 2, self.focal_px, self.focal_px * self.baseline_mm],
                self.offsets_mm[camera],
                self.rotations[camera].ravel(),
                lens.coefficients,
                [lens.fx, lens.fy, lens.cx, lens.cy],
            ]
        ).astype(np.float64)

    def place(
        self,
        camera: int,
        cx: NDArray[np.floating],
        cy: NDArray[np.floating],
        disparity: NDArray[np.floating],
    ) -> TilePlacement:
        """Camera ``camera``'s 16-sample windows of the tiles centred at (cx, cy), at a disparity.

        :func:`elphel_host.tp.geometry.window_at` of :meth:`pixels` (equal to it in
        every bit), computed by one compiled loop.
        """
        from elphel_host.tp.fused import lens_windows  # numba: loaded on first use

        x, y, d = _flat_points(cx, cy, disparity)
        shape = np.broadcast(cx, cy, disparity).shape
        if self.lenses[camera].residual is not None:
            at = self._flat_pixels(camera, x, y, d)
            left_x, shift_x = window_at(at[0].reshape(shape))
            top_y, shift_y = window_at(at[1].reshape(shape))
            return TilePlacement(left_x=left_x, shift_x=shift_x, top_y=top_y, shift_y=shift_y)
        first = np.empty((2, x.size), dtype=np.int64)
        shift = np.empty((2, x.size), dtype=np.float64)
        lens_windows(x, y, d, self.lens_parameters(camera), first, shift)
        return TilePlacement(
            left_x=first[0].reshape(shape),
            shift_x=shift[0].reshape(shape),
            top_y=first[1].reshape(shape),
            shift_y=shift[1].reshape(shape),
        )

    def _flat_pixels(self, camera: int, x: F64, y: F64, disparity: F64) -> F64:
        """:meth:`pixels` ``(2, N)`` of flat points, by the compiled loop plus any residual grid."""
        from elphel_host.tp.fused import lens_pixels  # numba: loaded on first use

        out = np.empty((2, x.size))
        lens_pixels(x, y, disparity, self.lens_parameters(camera), out)
        residual = self.lenses[camera].residual
        if residual is not None:  # the grid moves the model's pixel (0 at a pixel's centre)
            out += residual.at(out.T - 0.5).T
        return out

    def disparity_gain(
        self,
        cx: NDArray[np.floating],
        cy: NDArray[np.floating],
        pairs: Sequence[tuple[int, int]],
        vectors: F64,
    ) -> F64:
        """Per tile, the pixels the pairs' image separations move per unit of disparity.

        For pair (a, b) with lag vector ``v`` (its peak lies at ``D * v`` in the ideal
        geometry), the change of ``p_b - p_a`` per unit of D, projected on ``v`` and
        divided by ``|v|^2``; the mean over the pairs. 1 for an ideal quad.
        """
        x, y, zero = _flat_points(cx, cy, 0.0)
        moved = []
        for cam in range(len(self.lenses)):
            at0 = self._flat_pixels(cam, x, y, zero)
            at1 = self._flat_pixels(cam, x, y, zero + 1.0)
            moved.append((at1 - at0).T.reshape(*np.shape(cx), 2))
        gain = np.zeros(np.shape(cx))
        for (a, b), v in zip(pairs, np.asarray(vectors, dtype=np.float64), strict=True):
            gain += ((moved[b] - moved[a]) @ v) / float(v @ v)
        out: F64 = gain / len(pairs)
        return out

    def depth_optics(self, pixel_pitch_um: float | None = None) -> DepthOptics:
        """The virtual camera's optics for depth (only ``f / pitch`` matters: 1 um if None)."""
        pitch = 1.0 if pixel_pitch_um is None else float(pixel_pitch_um)
        return DepthOptics(self.focal_px * pitch / 1000.0, pitch, self.baseline_mm)


def _flat_points(
    cx: NDArray[np.floating], cy: NDArray[np.floating], disparity: NDArray[np.floating] | float
) -> tuple[F64, F64, F64]:
    """Points broadcast together, as contiguous float64 ``(N,)`` arrays."""
    x, y, d = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (cx, cy, disparity)))
    flat = [np.ascontiguousarray(a.ravel()) for a in (x, y, d)]
    return flat[0], flat[1], flat[2]


def scaled_lens(lens: CameraModel, scale: int) -> CameraModel:
    """The lens of the same camera on a grid up-sampled by ``scale`` (as MFSR's output).

    Pixel i of the original grid is centred at ``scale * i + (scale - 1) / 2`` of the
    up-sampled one (``cv2.resize``'s alignment; pixel (0, 0) at the centre of the first
    pixel, as calibration.json), so the focal lengths grow by ``scale``, the principal
    point maps to ``scale * c + (scale - 1) / 2`` and the image size grows by ``scale``;
    the distortion, acting on normalised coordinates, stays; a residual grid's offsets
    grow by ``scale``.

    Raises
    ------
    ValueError
        ``scale`` is not an integer >= 1.
    """
    if isinstance(scale, bool) or not isinstance(scale, int | np.integer) or scale < 1:
        raise ValueError(f"scale={scale!r}; allowed: an integer >= 1")
    s = int(scale)
    return CameraModel(
        lens.width * s,
        lens.height * s,
        lens.fx * s,
        lens.fy * s,
        lens.cx * s + (s - 1) / 2,
        lens.cy * s + (s - 1) / 2,
        lens.distortion,
        None if lens.residual is None else lens.residual.scaled(s),
    )


def scaled(calibration: CalibratedGeometry, scale: int) -> CalibratedGeometry:
    """The calibrated quad on images up-sampled by ``scale`` (each camera's MFSR output).

    Every lens as :func:`scaled_lens`, the virtual camera's focal length times ``scale``;
    rotations, offsets and the baseline stay. A point at continuous pixel ``p`` and
    disparity D of the original grid is at ``scale * p`` and ``scale * D`` of the new
    one, and its depth ``Z = f B / D`` is the same.
    """
    return CalibratedGeometry(
        tuple(scaled_lens(lens, scale) for lens in calibration.lenses),
        calibration.rotations,
        calibration.offsets_mm,
        calibration.focal_px * scale,
        calibration.baseline_mm,
    )


def read_calibration(path: str | Path) -> CalibratedGeometry:
    """The calibrated geometry of a calibration.json (or of a directory holding one).

    Raises
    ------
    InputFormatError
        The file is missing, is no calibration.json of version 1, or is not of a quad.
    """
    from elphel_host.calibrate.result import read_cameras  # the file's owner (imports cv2)

    p = calibration_file(path)
    if not p.is_file():
        raise InputFormatError(
            f"{p}: no such calibration file; allowed: the calibration.json that "
            "`elphel calibrate solve` writes (or its directory)"
        )
    try:
        cameras = read_cameras(p)
    except (ValueError, KeyError, TypeError, IndexError, json.JSONDecodeError) as e:
        raise InputFormatError(
            f"{p}: not a readable calibration.json ({type(e).__name__}: {e}); allowed: "
            "the file `elphel calibrate solve` writes"
        ) from e
    return CalibratedGeometry.from_cameras(cameras, source=str(p))


def calibration_file(path: str | Path) -> Path:
    """``path`` if it is a file, else the calibration.json of the directory ``path``."""
    p = Path(path)
    return p / CALIBRATION_FILE if p.is_dir() else p


def copy_calibration(
    source: str | Path, quad_dir: str | Path, *, image_size: tuple[int, int]
) -> str:
    """Copy a calibration into a quad directory; the name quad.json's ``calibration`` takes.

    Raises
    ------
    InputFormatError
        The calibration is unreadable, or for images of another size than ``image_size``
        (the message names both sizes).
    """
    src = calibration_file(source)
    cal = read_calibration(src)
    if cal.image_size != tuple(image_size):
        raise InputFormatError(
            f"{src} is for {cal.image_size[0]}x{cal.image_size[1]} images, the quad's are "
            f"{image_size[0]}x{image_size[1]}; allowed: a calibration of these cameras at "
            "the same image size (WOI)"
        )
    shutil.copyfile(src, Path(quad_dir) / CALIBRATION_FILE)
    return CALIBRATION_FILE
