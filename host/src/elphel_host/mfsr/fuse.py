"""Fuse a burst: registration, validation, then one of the methods, mono or Bayer.

Output grid (the burst format's contract): the first frame's grid up-sampled by ``scale``
with pixel centres where ``cv2.resize`` puts them (LR pixel i has its centre at HR coordinate
``scale * i + (scale - 1) / 2``), in the input's units. Bayer bursts give an RGB image:
each colour plane is reconstructed on that full grid from its own samples (both green
sites together), with the pixel aperture of the full-resolution pixel.
"""

from __future__ import annotations

import resource
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elphel_host.burst.io import Burst
from elphel_host.burst.manifest import check_bayer
from elphel_host.mfsr.baseline import fuse_baseline
from elphel_host.mfsr.bayer import bayer_luma, bayer_sites, demosaic_plane
from elphel_host.mfsr.frames import check_frames
from elphel_host.mfsr.psf_spec import GivenGrid
from elphel_host.mfsr.regions import fuse_regions
from elphel_host.mfsr.registration import FrameRegistration, register_frames
from elphel_host.mfsr.robust_config import DEFAULT_CONFIG, RobustConfig
from elphel_host.mfsr.robust_fuse import fuse_robust
from elphel_host.mfsr.scale import check_scale

F32 = NDArray[np.float32]

METHODS = ("robust", "baseline", "bicubic")


@dataclass(frozen=True)
class FusionResult:
    """What :func:`fuse_frames` returns.

    Attributes
    ----------
    image
        (H*S, W*S) float32, or (H*S, W*S, 3) RGB for a Bayer burst, in input units.
    method
        The method used.
    registrations
        Per-frame registration (at LR), including rejected frames.
    excluded
        Indices of the frames left out of the fusion.
    seconds
        Wall time of registration and fusion.
    info
        Method-specific details (noise estimate, refined shifts, ...).
    """

    image: F32
    method: str
    registrations: list[FrameRegistration]
    excluded: list[int]
    seconds: float
    info: dict[str, Any] = field(default_factory=dict)

    def report(self) -> dict[str, Any]:
        return {
            "method": self.method,
            "shape": list(self.image.shape),
            "frames": len(self.registrations),
            "used": len(self.registrations) - len(self.excluded),
            "excluded": [
                {"index": r.index, "reason": r.reason}
                for r in self.registrations
                if r.index in self.excluded
            ],
            "registration": [r.to_json() for r in self.registrations],
            "seconds": round(self.seconds, 3),
            "peak_memory_mb": round(peak_memory_mb(), 1),
            **{k: v for k, v in self.info.items() if k != "shifts_refined"},
        }


def peak_memory_mb() -> float:
    """Peak resident memory of this process so far (MB).

    Linux's ``VmHWM``: ``ru_maxrss`` keeps the peak of the process image before an
    ``exec``, so a command started from a large process (a benchmark, a notebook) would
    report its parent's memory.
    """
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def fuse_frames(
    frames: Sequence[NDArray[Any]] | NDArray[Any],
    *,
    scale: int,
    method: str = "robust",
    bayer: str | None = None,
    prior: Sequence[tuple[float, float]] | None = None,
    config: RobustConfig = DEFAULT_CONFIG,
    min_correlation: float = 0.5,
) -> FusionResult:
    """Register and fuse a burst's frames onto the first frame's grid up-sampled by ``scale``.

    Parameters
    ----------
    frames
        N 2-D frames of one size (any real dtype; uint16 DN from a burst directory).
    scale
        Integer up-sampling factor, 1..8.
    method
        ``robust`` (forward-model reconstruction), ``baseline`` (the published direct
        method) or ``bicubic`` (the first frame, ``cv2.resize`` bicubic).
    bayer
        Bayer pattern of a raw mosaic, or None for mono.
    prior
        Optional per-frame shift prior (dy, dx) in px from the stage and optics.
    config
        Options of the robust method.
    min_correlation
        Registration validation threshold (ECC correlation).
    """
    if method not in METHODS:
        raise ValueError(f"method={method!r}; allowed: {', '.join(METHODS)}")
    scale = check_scale(scale)
    check_bayer(bayer)
    fl = [np.asarray(f, dtype=np.float32) for f in frames]
    shape = check_frames(fl)
    if bayer is not None and (shape[0] % 2 or shape[1] % 2):
        raise ValueError(f"frame shape {shape}; allowed: even height and width for Bayer")
    t0 = time.perf_counter()
    if method == "bicubic":
        img = _bicubic(fl[0], scale, bayer)
        regs = [FrameRegistration(0, (0.0, 0.0), 1.0, "reference", True)]
        return FusionResult(img, method, regs, [], time.perf_counter() - t0)
    lumas = fl if bayer is None else [bayer_luma(f) for f in fl]
    regs = register_lumas(
        lumas, mosaic=bayer is not None, prior=prior, min_correlation=min_correlation
    )
    img, info = fuse_registered(fl, regs, scale=scale, method=method, bayer=bayer, config=config)
    excluded = [r.index for r in regs if not r.ok]
    return FusionResult(img, method, regs, excluded, time.perf_counter() - t0, info)


def register_lumas(
    lumas: Sequence[F32],
    *,
    mosaic: bool,
    prior: Sequence[tuple[float, float]] | None = None,
    min_correlation: float = 0.5,
) -> list[FrameRegistration]:
    """Register frames to the first; for Bayer mosaics their `bayer_luma` images.

    A mosaic's luminance has half its resolution: the prior (full-resolution px) is halved
    for registration and the shifts found are doubled back.
    """
    if not mosaic:
        return register_frames(lumas, prior=prior, min_correlation=min_correlation)
    half = None if prior is None else [(a / 2, b / 2) for a, b in prior]
    regs = register_frames(lumas, prior=half, min_correlation=min_correlation)
    return [
        replace(r, shift=None if r.shift is None else (2 * r.shift[0], 2 * r.shift[1]))
        for r in regs
    ]


def _check_psf_frame(config: RobustConfig, frame: tuple[int, ...]) -> None:
    """Given PSFs made for frames of one size refuse frames of another."""
    made_for = getattr(config.psf, "frame", None)
    if made_for is not None and tuple(frame) != made_for:
        raise ValueError(
            f"the given PSFs were made for {made_for[1]}x{made_for[0]} frames "
            f"(their quad's images); these frames are {frame[1]}x{frame[0]}; allowed: the "
            "same sensor area"
        )


def _fuse_baseline(
    frames: list[F32], used: list[int], *, scale: int, bayer: str | None
) -> tuple[NDArray[Any], dict[str, Any]]:
    """The published direct method on the used frames; each colour apart for Bayer."""
    if bayer is None:
        img, binfo = fuse_baseline([frames[i] for i in used], scale=scale)
    else:
        planes = []
        for sites in bayer_sites(bayer).values():
            # each colour: bilinear demosaic of that plane, then the published method
            ch = [demosaic_plane(frames[i], sites) for i in used]
            planes.append(fuse_baseline(ch, scale=scale)[0])
        img, binfo = np.stack(planes, axis=-1), {}
    info: dict[str, Any] = {"baseline_excluded": [used[i] for i in binfo.get("excluded", [])]}
    if "shifts" in binfo:  # ECC on the up-sampled frames, in LR px, for the used frames
        info["shifts"] = binfo["shifts"]
    return img, info


def fuse_registered(
    frames: Sequence[F32],
    regs: Sequence[FrameRegistration],
    *,
    scale: int,
    method: str,
    bayer: str | None,
    config: RobustConfig = DEFAULT_CONFIG,
) -> tuple[F32, dict[str, Any]]:
    """Fuse registered float32 frames (the frames whose registration is ok) with a method.

    Returns the image (RGB for a Bayer burst) and the method's details.
    """
    ok = [r for r in regs if r.ok]
    if method == "baseline":
        img, info = _fuse_baseline(list(frames), [r.index for r in ok], scale=scale, bayer=bayer)
        return np.asarray(img, np.float32), info
    _check_psf_frame(config, frames[0].shape)
    used = [frames[r.index] for r in ok]
    shifts = [r.shift for r in ok if r.shift is not None]
    psf = config.psf
    if isinstance(psf, GivenGrid) and psf.regions != (1, 1):
        img, info = fuse_regions(used, shifts, scale=scale, bayer=bayer, grid=psf, config=config)
    else:
        if isinstance(psf, GivenGrid):
            config = replace(config, psf=psf.cell(0, 0))
        img, info = fuse_robust(used, shifts, scale=scale, bayer=bayer, config=config)
    return np.asarray(img, np.float32), info


def _bicubic(frame: F32, scale: int, bayer: str | None) -> F32:
    if bayer is None:
        planes = [frame]
    else:
        planes = [demosaic_plane(frame, s) for s in bayer_sites(bayer).values()]
    up = [cv2.resize(p, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC) for p in planes]
    return np.asarray(up[0] if bayer is None else np.stack(up, axis=-1), dtype=np.float32)


def fuse_burst(
    burst: Burst,
    *,
    scale: int,
    method: str = "robust",
    config: RobustConfig = DEFAULT_CONFIG,
    use_prior: bool = True,
) -> FusionResult:
    """:func:`fuse_frames` on a loaded burst directory, with its stage/optics prior."""
    prior = burst.stage_prior_px() if use_prior else None
    return fuse_frames(
        list(burst.frames),
        scale=scale,
        method=method,
        bayer=burst.bayer,
        prior=prior,
        config=config,
    )
