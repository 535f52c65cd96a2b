"""Options of the tile processor: one frozen, checked :class:`TpConfig`."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class TpConfig:
    """Options of the tile processor.

    Attributes
    ----------
    fat_zero
        Absolute fat zero of the normalisation, in units of the CLT product of images
        scaled to full scale 1.0; frequencies much weaker than this are suppressed.
    lpf_sigma
        Correlation LPF: sigma of a Gaussian of the lag
        (`~elphel_host.tp.correlation.lpf_mask`; 0 = none).
    lpf_sigma_rb
        Extra LPF of the red and blue correlations (0 = none). Red and blue are sampled
        every second pixel, so their spectra above a quarter of the sampling rate are
        mostly alias, and an alias moves the wrong way under a phase rotation.
    green_band
        Green frequencies kept: ``kh + kv <= green_band`` (14 = all). The green
        checkerboard aliases across the anti-diagonal ``kh + kv = 7``.
    red_weight, blue_weight
        Colour weights relative to green.
    radius
        Correlation reach in pixels of residual disparity per pass.
    refine_passes
        Passes after the first, each re-centred on the disparity measured so far.
    first_pass_step
        The first pass measures every n-th tile along each axis (1 = every tile); the
        tiles between take their first-pass correlation from the nearest measured one.
        Only the refinement's targets come from it, and the refinement measures every
        tile (with no refinement pass, the first pass measures every tile).
    scan
        Target disparities of the first pass; with several, each tile keeps the one whose
        correlation is strongest (for objects nearer than ``radius`` allows from 0).
    disparity_scale
        Measured residuals are divided by this (Elphel's ``corr_magic_scale``, 0.85 there):
        the window pulls the correlation peak towards lag 0 by about 13 % here.
    min_disparity
        Smallest disparity searched (a little below 0 = infinity, for calibration errors);
        keeps weak far-off noise peaks from winning against a strong near object.
    chunk_tiles
        Most tiles per chunk (chunks are equal, their number a multiple of 4).
    threads
        Worker threads (1 = run in the calling thread).
    pairs
        Indices into ``QuadGeometry.pairs`` used in the combined disparity.
    """

    fat_zero: float = 0.002
    lpf_sigma: float = 0.8
    lpf_sigma_rb: float = 3.0
    green_band: int = 5
    red_weight: float = 0.5
    blue_weight: float = 0.2
    radius: int = 7
    refine_passes: int = 1
    first_pass_step: int = 2
    scan: tuple[float, ...] = (0.0,)
    disparity_scale: float = 0.87
    min_disparity: float = -1.0
    chunk_tiles: int = 2048
    threads: int = 2
    pairs: tuple[int, ...] = (0, 1, 2, 3, 4, 5)

    def __post_init__(self) -> None:
        checks = (
            ("fat_zero", self.fat_zero >= 0, ">= 0"),
            ("lpf_sigma", self.lpf_sigma >= 0, ">= 0"),
            ("lpf_sigma_rb", self.lpf_sigma_rb >= 0, ">= 0"),
            ("green_band", 0 <= self.green_band <= 14, "0..14"),
            ("radius", 1 <= self.radius <= 7, "1..7"),
            ("refine_passes", self.refine_passes >= 0, ">= 0"),
            ("first_pass_step", 1 <= self.first_pass_step <= 4, "1..4"),
            ("disparity_scale", self.disparity_scale > 0, "> 0"),
            ("chunk_tiles", self.chunk_tiles >= 1, ">= 1"),
            ("threads", self.threads >= 1, ">= 1"),
            ("scan", len(self.scan) >= 1, "at least one disparity"),
            ("pairs", len(self.pairs) >= 1 and all(0 <= p < 6 for p in self.pairs), "indices 0..5"),
        )
        for name, ok, allowed in checks:
            if not ok:
                raise ValueError(f"{name}={getattr(self, name)!r}; allowed: {allowed}")


#: The default options (a module-level value, so signatures can use it as a default).
DEFAULT_CONFIG = TpConfig()
