"""The robust method on registered frames with one PSF: a mono image or a Bayer burst's RGB.

A Bayer burst's colour planes are each reconstructed on the full output grid from their
own samples, with the pixel aperture of the full-resolution pixel, and solved together
(:func:`~elphel_host.mfsr.robust.reconstruct_planes`): their noise measured per colour,
the shifts refined once and the lens resolved once, on green (twice the samples), and
every solve of the three one batched block solve. One lens serves the three colours
unless the given PSF has each colour's own.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from elphel_host.mfsr.bayer import bayer_sites, colour_planes, frame_shifts, site_shifts
from elphel_host.mfsr.psf_spec import GivenKernel
from elphel_host.mfsr.robust import ResolvedPsf, reconstruct, reconstruct_planes
from elphel_host.mfsr.robust_config import RobustConfig
from elphel_host.mfsr.solve import Geometry

F32 = NDArray[np.float32]
_GREEN = 1


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
    sites = list(bayer_sites(bayer).values())

    def spread(green: list[tuple[float, float]]) -> list[list[tuple[float, float]]]:
        refined = frame_shifts(green, sites[_GREEN])
        return [site_shifts(refined, s) for s in sites]

    def own(psf: ResolvedPsf, colour: int) -> ResolvedPsf:
        return psf.for_colour(config.psf, colour)

    results, psf = reconstruct_planes(
        colour_planes(frames, shifts, bayer),
        Geometry(2 * scale, scale),
        config,
        key=_GREEN,
        spread=spread,
        colour_psf=own,
    )
    report = dict(psf.report)
    if isinstance(config.psf, GivenKernel) and config.psf.rgb is not None:
        report["per_colour"] = True
    noise = [info["noise_sigma"] for _, info in results]
    image = np.stack([img for img, _ in results], axis=-1)
    return image, {"noise_sigma_rgb": noise, "psf": report}
