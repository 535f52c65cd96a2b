"""The renderer: camera model -> sensor image.

`radiance` integrates the scene's radiance over each pixel's footprint (sub-pixel exact,
moving planes at each strip's time; a frame of a still scene seen again from the same
pose is reused from `RADIANCE_CACHE`); `sensor` reads it out as a sensor does (Bayer
mosaic, per-colour gains, exposure, shot and read noise, 12- or 14-bit quantisation,
flips); `optics` blurs it as a lens does (`blurred_strips`). Everything a caller needs
is importable from here.
"""

from __future__ import annotations

from elphel_sim.render.optics import MAX_LENS_BLUR_PX, LensBlur, blurred_strips, check_lens_blur
from elphel_sim.render.radiance import Intrinsics, Window, render_radiance, render_strips
from elphel_sim.render.radiance_cache import RADIANCE_CACHE, RadianceCache
from elphel_sim.render.sensor import (
    BAYER_PATTERNS,
    Readout,
    SensorModel,
    bayer_channels,
    expose,
    mosaic,
    read_out,
)

__all__ = [
    "BAYER_PATTERNS",
    "MAX_LENS_BLUR_PX",
    "RADIANCE_CACHE",
    "Intrinsics",
    "LensBlur",
    "RadianceCache",
    "Readout",
    "SensorModel",
    "Window",
    "bayer_channels",
    "blurred_strips",
    "check_lens_blur",
    "expose",
    "mosaic",
    "read_out",
    "render_radiance",
    "render_strips",
]
