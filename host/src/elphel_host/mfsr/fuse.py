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
from elphel_host.mfsr.frames import check_frames
from elphel_host.mfsr.registration import FrameRegistration, register_frames
from elphel_host.mfsr.robust import psf_for, reconstruct, with_psf
from elphel_host.mfsr.robust_config import DEFAULT_CONFIG, RobustConfig
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


def bayer_luma(mosaic: F32) -> F32:
    """2x2-cell mean: a half-resolution luminance for registration."""
    h, w = mosaic.shape
    a = mosaic[: h // 2 * 2, : w // 2 * 2]
    return np.asarray(a.reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3)), dtype=np.float32)


def bayer_sites(bayer: str) -> dict[str, list[tuple[int, int]]]:
    out: dict[str, list[tuple[int, int]]] = {"R": [], "G": [], "B": []}
    for idx, c in enumerate(bayer):
        out[c].append((idx // 2, idx % 2))
    return out


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
    frame = tuple(frames[0].shape)
    if method == "robust" and config.psf_frame is not None and frame != config.psf_frame:
        raise ValueError(
            f"the given PSFs were made for {config.psf_frame[1]}x{config.psf_frame[0]} frames "
            f"(their quad's images); these frames are {frame[1]}x{frame[0]}; allowed: the "
            "same sensor area"
        )
    if method == "robust" and config.psf_regions != (1, 1):
        from elphel_host.mfsr.regions import fuse_regions

        return fuse_regions(frames, regs, scale=scale, bayer=bayer, config=config)
    fl = list(frames)
    used = [r.index for r in regs if r.ok]
    shifts = [regs[i].shift for i in used]
    info: dict[str, Any] = {}
    img: NDArray[Any]
    if method == "baseline":
        if bayer is None:
            img, binfo = fuse_baseline([fl[i] for i in used], scale=scale)
        else:
            planes = []
            for sites in bayer_sites(bayer).values():
                # each colour: bilinear demosaic of that plane, then the published method
                ch = [demosaic_plane(fl[i], sites) for i in used]
                planes.append(fuse_baseline(ch, scale=scale)[0])
            img, binfo = np.stack(planes, axis=-1), {}
        info["baseline_excluded"] = [used[i] for i in binfo.get("excluded", [])]
        if "shifts" in binfo:  # ECC on the up-sampled frames, in LR px, for the used frames
            info["shifts"] = binfo["shifts"]
    elif bayer is None:
        img, rinfo = reconstruct(
            [fl[i] for i in used],
            shifts,  # type: ignore[arg-type]
            scale=scale,
            config=config,
        )
        info.update(rinfo)
    else:
        colours: list[tuple[list[F32], list[tuple[float, float]]]] = []
        for sites in bayer_sites(bayer).values():
            pf: list[F32] = []
            ps: list[tuple[float, float]] = []
            for i, s in zip(used, shifts, strict=True):
                assert s is not None
                for oy, ox in sites:
                    pf.append(np.ascontiguousarray(fl[i][oy::2, ox::2]))
                    ps.append(((oy + s[0] - 0.5) / 2, (ox + s[1] - 0.5) / 2))
            colours.append((pf, ps))
        # one lens for the three colours: estimated on green (twice the samples)
        psf = psf_for(*colours[1], scale=2 * scale, aperture=scale, config=config)
        config = with_psf(config, psf)
        planes = []
        for c, (pf, ps) in enumerate(colours):
            own = config  # or the colour's own given PSF
            if config.psf_rgb is not None:
                own = replace(config, psf_kernel=config.psf_rgb[c], psf_rgb=None)
            plane, rinfo = reconstruct(pf, ps, scale=2 * scale, aperture=scale, config=own)
            planes.append(plane)
            info.setdefault("noise_sigma_rgb", []).append(rinfo["noise_sigma"])
        info["psf"] = {**psf.to_json(), "tau_used": round(config.tau, 4)}
        if config.psf_rgb is not None:
            info["psf"]["per_colour"] = True
        img = np.stack(planes, axis=-1)
    return np.asarray(img, np.float32), info


def demosaic_plane(mosaic: F32, sites: list[tuple[int, int]]) -> F32:
    """One colour at every pixel by normalised bilinear interpolation of its sites."""
    vals = np.zeros_like(mosaic)
    mask = np.zeros_like(mosaic)
    for oy, ox in sites:
        vals[oy::2, ox::2] = mosaic[oy::2, ox::2]
        mask[oy::2, ox::2] = 1.0
    k = np.array([[0.25, 0.5, 0.25], [0.5, 1.0, 0.5], [0.25, 0.5, 0.25]], np.float32)
    num = cv2.filter2D(vals, -1, k, borderType=cv2.BORDER_REFLECT_101)
    den = cv2.filter2D(mask, -1, k, borderType=cv2.BORDER_REFLECT_101)
    return np.asarray(num / np.maximum(den, 1e-6), dtype=np.float32)


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
