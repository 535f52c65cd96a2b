"""A calibrated quad burst's raw views: each camera's parallax map and the fused quad's calibration.

The fusion of a camera's burst moves each of its samples by ``D(q) * v_k``
(:mod:`elphel_host.mfsr.local_motion`), D the disparity at the camera's pixel q and
``v_k`` the frame's shift per pixel of disparity. A calibrated quad's disparity is the
virtual centre camera's (:mod:`elphel_host.tp.calibrated`), measured on its pixels, while
the bursts are the cameras' raw, distorted images. When the carriage moves, a point the
virtual camera sees at p with disparity D moves there to ``p + D v_k`` at the same
disparity, so in camera i it moves from ``P_i(p, D)`` to ``P_i(p + D v_k, D)``, P_i the
calibrated map (``CalibratedGeometry.pixels``). :func:`raw_view` gives camera i,
at each raw pixel q, the motion ``D(p) m_i(q)`` per unit of ``v_k``, p the virtual pixel
it sees at q and ``m_i`` the change of ``P_i`` per pixel of p along the carriage's axis.
The fusion takes a scalar map times one direction per frame, so the motion is written
as ``D(p) (m_i . w_i)`` along ``w_i``, the mean direction of ``m_i`` (the axis turned by
the camera's roll; :meth:`RawView.model` turns ``v_k`` onto it): exact to first order
along ``w_i``; the lens's shear across it (towards the corners of a barrel lens, where
the radial and tangential scales differ, a few per cent of the motion) is left out.

:func:`calibration_document` writes a calibrated geometry back as a calibration.json, so
that the fused quad (``elphel depth``'s ``fused/``) carries the calibration of its
up-sampled grid.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elphel_host.calibrate.result import VERSION
from elphel_host.mfsr.local_motion import ParallaxModel
from elphel_host.tp.calibrated import CalibratedGeometry

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]


def motion_direction(per_disparity: Sequence[tuple[float, float]]) -> tuple[float, float]:
    """Unit (dy, dx) of the largest of the frames' shifts; (0, 1) if none moves."""
    vy, vx = max(per_disparity, key=lambda v: float(np.hypot(*v)), default=(0.0, 0.0))
    n = float(np.hypot(vy, vx))
    return (0.0, 1.0) if n == 0 else (vy / n, vx / n)


def _sample(field: F32, x: F64, y: F64) -> F64:
    """``field`` (pixel centres at i + 0.5) at continuous pixels, edges replicated."""
    got = cv2.remap(
        field,
        (x - 0.5).astype(np.float32),
        (y - 0.5).astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    return np.asarray(got, dtype=np.float64)


@dataclass(frozen=True, eq=False)
class RawView:
    """How one camera's raw view moves with the carriage (:func:`raw_view`).

    Attributes
    ----------
    disparity
        ``(H, W)`` float32: per raw pixel, the virtual camera's disparity there times the
        lens's scale along ``direction``.
    direction
        Unit (dy, dx): the raw image's mean direction of motion (the carriage's axis
        turned by the camera's roll).
    gain
        ``(H, W)`` float32: the lens's scale along ``direction`` per raw pixel (the
        factor in ``disparity``).
    """

    disparity: F32
    direction: tuple[float, float]
    gain: F32

    def model(self, virtual: ParallaxModel, axis: tuple[float, float]) -> ParallaxModel:
        """The frames' shifts per px of disparity in this view.

        ``virtual``'s shifts along ``axis`` (a unit (dy, dx)), turned onto
        :attr:`direction`.
        """
        ay, ax = axis
        wy, wx = self.direction
        along = [vy * ay + vx * ax for vy, vx in virtual.per_disparity]
        return ParallaxModel(tuple((a * wy, a * wx) for a in along))


def raw_view(
    centre: F32,
    calibration: CalibratedGeometry,
    camera: int,
    *,
    direction: tuple[float, float],
    steps: int = 10,
) -> RawView:
    """The virtual camera's per-pixel disparity moved into camera ``camera``'s raw view.

    Parameters
    ----------
    centre
        ``(H, W)`` disparity of the virtual centre camera at its pixels (the calibration's
        image size).
    calibration
        The quad's calibrated geometry.
    camera
        Which camera's raw view.
    direction
        Unit (dy, dx) of the carriage's image motion in the virtual camera
        (:func:`motion_direction`).
    steps
        Fixed-point steps that find the virtual pixel p each raw pixel q sees
        (``P(p, D(p)) = q``; the lens's scale is near 1, so each step shrinks the error
        several times).

    Returns
    -------
    The raw view: per raw pixel q the motion ``D(p) m(q)``, m the change of ``P`` per
    pixel of p along ``direction``, written as a scalar map times a unit direction (the
    mean of m): the map is ``D(p) m(q)`` projected on that direction.
    """
    h, w = centre.shape
    if calibration.image_size != (w, h):
        raise ValueError(
            f"disparity map {w}x{h}, calibration for {calibration.image_size[0]}x"
            f"{calibration.image_size[1]}; allowed: the same size"
        )
    field = np.ascontiguousarray(centre, dtype=np.float32)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
    px, py = xs.copy(), ys.copy()
    for _ in range(steps):
        qx, qy = calibration.pixels(camera, px, py, _sample(field, px, py))
        px += xs - qx
        py += ys - qy
    d = _sample(field, px, py)
    dy, dx = direction
    ax, ay = calibration.pixels(camera, px, py, d)
    bx, by = calibration.pixels(camera, px + dx, py + dy, d)
    my, mx = by - ay, bx - ax
    wy, wx = float(np.mean(my)), float(np.mean(mx))
    n = float(np.hypot(wy, wx))
    wy, wx = wy / n, wx / n
    gain = my * wy + mx * wx
    return RawView((d * gain).astype(np.float32), (wy, wx), gain.astype(np.float32))


def calibration_document(calibration: CalibratedGeometry) -> dict[str, Any]:
    """A calibration.json (version 1) whose calibrated geometry is ``calibration``.

    Camera 0 is at the origin of its own frame; camera i's ``R`` and ``t_mm`` put it at
    its offset from camera 0 with its rotation, which is all the geometry keeps.
    """
    offsets = calibration.offsets_mm - calibration.offsets_mm[0]
    cameras = []
    for lens, r, centre in zip(calibration.lenses, calibration.rotations, offsets, strict=True):
        t_mm = -r @ centre
        cameras.append({**lens.to_json(), "R": r.tolist(), "t_mm": t_mm.tolist()})
    return {"version": VERSION, "pattern": None, "rms_px": None, "cameras": cameras}
