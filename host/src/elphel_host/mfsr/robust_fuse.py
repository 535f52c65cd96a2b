"""The robust method on registered frames with one PSF: a mono image or a Bayer burst's RGB.

A Bayer burst's colour planes are each reconstructed on the full output grid from their
own samples, with the pixel aperture of the full-resolution pixel; one lens serves the
three colours, resolved on green (twice the samples), unless the given PSF has each
colour's own.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elphel_host.mfsr.bayer import colour_planes
from elphel_host.mfsr.psf_spec import GivenKernel
from elphel_host.mfsr.robust import reconstruct, reconstruct_resolved, resolve_psf
from elphel_host.mfsr.robust_config import RobustConfig
from elphel_host.mfsr.solve import Geometry

F32 = NDArray[np.float32]


def fuse_robust(
    frames: Sequence[F32],
    shifts: Sequence[tuple[float, float]],
    *,
    scale: int,
    bayer: str | None,
    config: RobustConfig,
) -> tuple[F32, dict[str, Any]]:
    """Reconstruct the used frames (``frames[0]`` the reference) with ``config.psf``.

    ``config.psf`` is one PSF for the frames (not a grid). Returns the image (RGB for a
    Bayer burst) and the reconstruction's details.
    """
    if bayer is None:
        return reconstruct(frames, shifts, scale=scale, config=config)
    colours = colour_planes(frames, shifts, bayer)
    geometry = Geometry(2 * scale, scale)
    psf = resolve_psf(*colours[1], geometry, config)
    planes, noise = [], []
    for c, (pf, ps) in enumerate(colours):
        own = psf.for_colour(config.psf, c)
        plane, rinfo = reconstruct_resolved(pf, ps, geometry, own, config)
        planes.append(plane)
        noise.append(rinfo["noise_sigma"])
    report = dict(psf.report)
    if isinstance(config.psf, GivenKernel) and config.psf.rgb is not None:
        report["per_colour"] = True
    return np.stack(planes, axis=-1), {"noise_sigma_rgb": noise, "psf": report}
