"""The quad's scene as a real, calibrated quad records it, and as an ideal quad would.

`render_raw_quad` renders a :class:`~elphel_sim.quad.QuadScene` through the cameras of a
:class:`~elphel_sim.calib_rig.CalibRig`: each with its own lens distortion (OpenCV's
rational model plus its smooth residual), focal length, principal point and small
rotation, at its place on the square. These are the raw images `elphel tp` takes with a
calibration. `rectified_rig` is the same rig made ideal: four identical distortion-free
pinhole cameras with the rig's mean focal length, looking along camera 0's axis from the
same centres; `elphel_sim.quad.render_quad` of the same scene with it gives the images a
common-model quad records, and `elphel_sim.quad.tile_truth` the true disparity of every
tile of the virtual centre camera, which is also the calibrated tile processor's.
`drifted_rig` is the rig after its cameras 1-3 turned and zoomed a little (as a warm rig
does; `elphel calibrate field` finds it again).

The scene's frame is the rectified rig's: the virtual centre camera at the origin
looking along +z, which is camera 0's frame moved to the centre of the four cameras.
Each pixel's radiance is the scene's band-limited texture, averaged over the pixel's
footprint on the plane it sees (the footprint taken where the plane's visible part is
centred, as `elphel_sim.render.render_radiance` does).
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from elphel_host.calibrate.field import CORRECTIONS, apply_corrections, pixels_per_unit
from elphel_host.tp import io as quad_format
from elphel_host.tp.calibrated import CALIBRATION_FILE, CalibratedGeometry, copy_calibration
from elphel_sim.calib_rig import QUAD_POSITIONS, CalibRig, RigCamera
from elphel_sim.quad import QuadRig, QuadScene
from elphel_sim.quad_truth import nearest_hits
from elphel_sim.render import expose, mosaic
from elphel_sim.render.radiance import filtered_coefficients

FloatArray = NDArray[np.float64]

#: The sides of the square: (0, 1), (2, 3), (0, 2), (1, 3).
SIDES = ((0, 1), (2, 3), (0, 2), (1, 3))


def camera_centres_mm(rig: CalibRig) -> FloatArray:
    """Each camera's centre ``(4, 3)`` in the scene's frame (relative to the rig's centre)."""
    centres = np.stack([-cam.R.T @ cam.t_mm for cam in rig.cameras])
    out: FloatArray = centres - centres.mean(axis=0)
    return out


def rectified_rig(rig: CalibRig, *, focal_length_mm: float = 4.5) -> QuadRig:
    """The rig made ideal: pinhole cameras of its mean focal length on its mean square.

    Only ``focal_length_mm / pixel_pitch_um`` matters; the pitch is chosen to give the
    rig's mean focal length in pixels.
    """
    if len(rig.cameras) != 4:
        raise ValueError(f"a rig of {len(rig.cameras)} cameras; allowed: 4")
    w, h = rig.size
    focal_px = float(np.mean([(c.lens.fx + c.lens.fy) / 2 for c in rig.cameras]))
    c = camera_centres_mm(rig)
    side = float(np.mean([np.linalg.norm(c[a] - c[b]) for a, b in SIDES]))
    return QuadRig(
        width=w,
        height=h,
        focal_length_mm=focal_length_mm,
        pixel_pitch_um=focal_length_mm * 1000.0 / focal_px,
        baseline_mm=side,
        bayer=rig.bayer,
    )


def _rays(cam: RigCamera, pixels: FloatArray) -> FloatArray:
    """Directions ``(N, 3)`` in the scene's frame of the rays through pixels ``(N, 2)``."""
    model = cam.model_pixels(pixels) if any(t[1] for t in cam.residual.terms) else pixels
    xy = cam.lens.rays(model)
    d = np.column_stack([xy, np.ones(len(xy))])
    out: FloatArray = d @ cam.R  # R^T d, row by row
    return out


def _plane_coordinates(
    region_plane: object, origin: FloatArray, d: FloatArray, t: FloatArray
) -> tuple[FloatArray, FloatArray]:
    u, v, _ = region_plane.basis()  # type: ignore[attr-defined]
    rel = origin + t[:, None] * d - np.asarray(region_plane.origin)  # type: ignore[attr-defined]
    return rel @ u, rel @ v


def _footprint(cam: RigCamera, plane: object, origin: FloatArray, pixel: FloatArray) -> FloatArray:
    """Jacobian d(s_u, s_v)/d(x, y) (mm per pixel) of the plane's coordinates at a pixel."""
    probe = pixel[None, :] + np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    d = _rays(cam, probe)
    _, _, n = plane.basis()  # type: ignore[attr-defined]
    t = ((np.asarray(plane.origin) - origin) @ n) / (d @ n)  # type: ignore[attr-defined]
    su, sv = _plane_coordinates(plane, origin, d, t)
    return np.array([[su[1] - su[0], su[2] - su[0]], [sv[1] - sv[0], sv[2] - sv[0]]])


def raw_radiance(scene: QuadScene, cam: RigCamera, origin_mm: FloatArray) -> FloatArray:
    """Linear RGB radiance ``(H, W, 3)`` one camera at ``origin_mm`` records of the scene."""
    w, h = cam.lens.width, cam.lens.height
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    pixels = np.column_stack([xs.ravel(), ys.ravel()])
    d = _rays(cam, pixels)
    t, label = nearest_hits(scene.regions, d, origin_mm)
    out = np.full((h * w, 3), float(scene.scene.background))
    for i, region in enumerate(scene.regions):
        seen = np.flatnonzero(label == i)
        if seen.size == 0:
            continue
        plane = region.plane
        tex = plane.texture
        grid_per_mm = tex.size / tex.period_mm
        # the footprint where the visible part is centred (as render_radiance takes it)
        mid = np.array([int(np.median(seen % w)), int(np.median(seen // w))], dtype=np.float64)
        coeffs = filtered_coefficients(tex, _footprint(cam, plane, origin_mm, mid) * grid_per_mm)
        su, sv = _plane_coordinates(plane, origin_mm, d[seen], t[seen])
        value = ndimage.map_coordinates(
            coeffs,
            [np.mod(sv * grid_per_mm, tex.size), np.mod(su * grid_per_mm, tex.size)],
            order=3,
            mode="grid-wrap",
            prefilter=False,
        )
        out[seen] = value[:, None] * np.asarray(plane.albedo_rgb, dtype=np.float64)
    return out.reshape(h, w, 3)


def render_raw_quad(scene: QuadScene, rig: CalibRig, *, seed: int | None = 0) -> NDArray[np.uint16]:
    """The four raw images ``(4, H, W)`` uint16 the rig's cameras record of the scene.

    Bayer mosaic or mono as the rig's; shot and read noise of its sensor when ``seed``.
    """
    if rig.size != (scene.rig.width, scene.rig.height):
        raise ValueError(
            f"rig of {rig.size[0]}x{rig.size[1]} images, scene for "
            f"{scene.rig.width}x{scene.rig.height}; allowed: the same size"
        )
    rng = None if seed is None else np.random.default_rng(seed)
    centres = camera_centres_mm(rig)
    out = []
    for cam, origin in zip(rig.cameras, centres, strict=True):
        raw = mosaic(raw_radiance(scene, cam, origin), rig.bayer)
        out.append(expose(raw, exposure_us=rig.exposure_us, model=rig.sensor, rng=rng))
    return np.stack(out)


def true_calibration(rig: CalibRig) -> dict[str, object]:
    """A calibration.json document of the rig's true lenses and poses (docs/calibration.md).

    The smooth residual of each lens is not in it (calibration.json has no place for it).
    """
    return {
        "version": 1,
        "pattern": None,
        "rms_px": 0.0,
        "cameras": [
            {**cam.lens.to_json(), "R": cam.R.tolist(), "t_mm": cam.t_mm.tolist()}
            for cam in rig.cameras
        ],
    }


def write_raw_quad_dir(
    path: str | Path,
    images: NDArray[np.uint16],
    rig: CalibRig,
    *,
    calibration: str | Path | None = None,
) -> Path:
    """Write a quad directory of raw images (and a copy of ``calibration``, named in quad.json).

    ``calibration``: a calibration.json or its directory, for images of the rig's size.
    """
    root = Path(path)
    root.mkdir(parents=True, exist_ok=True)
    name = None
    if calibration is not None:
        name = copy_calibration(calibration, root, image_size=rig.size)
    manifest = quad_format.QuadManifest(
        cameras=quad_format.quad_cameras(QUAD_POSITIONS),
        bayer=rig.bayer,
        full_scale_dn=(1 << rig.sensor.bits) - 1,
        calibration=name,
    )
    return quad_format.write_quad_dir(root, manifest, list(images))


def write_true_calibration(path: str | Path, rig: CalibRig) -> Path:
    """Write :func:`true_calibration` as ``path/calibration.json``; return the file."""
    out = Path(path)
    out.mkdir(parents=True, exist_ok=True)
    target = out / CALIBRATION_FILE
    target.write_text(json.dumps(true_calibration(rig), indent=1) + "\n")
    return target


def random_drift_px(max_px: float, *, seed: int, min_px: float = 0.3) -> FloatArray:
    """A drift ``(4, 4)`` for `drifted_rig`: camera 0 stays, cameras 1-3 drift.

    Each correction of cameras 1-3 is between ``min_px`` and ``max_px`` pixels, of random
    sign.
    """
    if not 0 < min_px <= max_px:
        raise ValueError(f"drift of {min_px}..{max_px} px; allowed: 0 < min_px <= max_px")
    rng = np.random.default_rng(seed)
    out = rng.uniform(min_px, max_px, (4, len(CORRECTIONS)))
    out *= rng.choice([-1.0, 1.0], out.shape)
    out[0] = 0.0
    return out


def drifted_rig(rig: CalibRig, drift_px: FloatArray) -> CalibRig:
    """The rig with each camera turned and zoomed by ``drift_px`` ``(4, 4)``.

    Per camera (tilt, azimuth, roll, zoom) in pixels: tilt and azimuth at the image's
    centre, roll and zoom at its corner (`elphel_host.calibrate.field.pixels_per_unit`);
    each camera turns about its own centre (`elphel_host.calibrate.field.apply_corrections`).
    """
    drift = np.asarray(drift_px, dtype=np.float64)
    if drift.shape != (len(rig.cameras), len(CORRECTIONS)):
        raise ValueError(f"drift of shape {drift.shape}; allowed: ({len(rig.cameras)}, 4)")
    units = np.stack([d / pixels_per_unit(c.lens) for d, c in zip(drift, rig.cameras, strict=True)])
    cams = apply_corrections([(c.lens, c.R, c.t_mm) for c in rig.cameras], units)
    moved = [
        replace(c, lens=lens, R=r, t_mm=t)
        for c, (lens, r, t) in zip(rig.cameras, cams, strict=True)
    ]
    return replace(rig, cameras=tuple(moved))


def misalignment_px(got: CalibratedGeometry, truth: CalibratedGeometry) -> FloatArray:
    """How far ``got`` puts cameras 1-3's tiles of points at infinity from ``truth``'s.

    For every tile centre (8 px apart, 16 px from the edges) at disparity 0, camera 0's
    pixel in ``got`` is seen by ``truth``'s camera 0 in some direction; each other
    camera's pixel in ``got`` is compared with where ``truth``'s camera sees that
    direction. Returns per camera 1-3 the RMS of the distance (px). Neither geometry's
    choice of virtual camera enters: only the cameras relative to camera 0 do.
    """
    w, h = got.image_size
    grid = np.mgrid[16 : h - 16 : 8, 16 : w - 16 : 8].astype(np.float64) + 4.0
    cy, cx = grid[0].ravel(), grid[1].ravel()
    zero = np.zeros_like(cx)
    want0 = np.stack(got.pixels(0, cx, cy, zero), -1)
    ux, uy = cx.copy(), cy.copy()
    for _ in range(8):  # truth's virtual pixel whose camera 0 pixel is want0 (Newton)
        at = np.stack(truth.pixels(0, ux, uy, zero), -1)
        jx = np.stack(truth.pixels(0, ux + 0.5, uy, zero), -1) - at
        jy = np.stack(truth.pixels(0, ux, uy + 0.5, zero), -1) - at
        step = np.linalg.solve(np.stack([jx, jy], -1) / 0.5, (want0 - at)[..., None])[..., 0]
        ux, uy = ux + step[:, 0], uy + step[:, 1]
    out = []
    for cam in (1, 2, 3):
        placed = np.stack(got.pixels(cam, cx, cy, zero), -1)
        seen = np.stack(truth.pixels(cam, ux, uy, zero), -1)
        out.append(float(np.sqrt(np.mean(np.sum((placed - seen) ** 2, -1)))))
    return np.array(out)
