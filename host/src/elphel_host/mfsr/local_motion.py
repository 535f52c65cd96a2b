"""Local (per-block) motion for bursts of a 3-D scene taken from a moving carriage.

When the carriage moves by ``s`` mm along an axis at angle theta to the sensor rows, a
surface at disparity D (pixels between two cameras one baseline B apart) moves by
``D * s / B`` pixels along that axis: near surfaces move more than far ones, so one
global shift per frame cannot register the frames. Here the motion of frame k is
``shift_k(p) = D(p) * v_k``, with ``v_k`` the frame's shift per pixel of disparity (from
the caliper positions and the axis angle, or from the global registration divided by the
disparity of the registration window) and D(p) the quad's own disparity map.

`fuse_local` cuts the frame into blocks, gives each block the shifts of its median
disparity and fuses it with the usual method (:func:`elphel_host.mfsr.fuse.fuse_registered`),
then pastes the blocks' interiors together. A block that straddles a depth edge is
registered for its majority depth, so the minority side is blurred there. A scene without
depth (a single disparity) gives every block the same shifts: use the global fusion then.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elphel_host.mfsr.fuse import fuse_registered
from elphel_host.mfsr.registration import FrameRegistration
from elphel_host.mfsr.robust_config import DEFAULT_CONFIG, RobustConfig
from elphel_host.parallel import parallel_map

F32 = NDArray[np.float32]


@dataclass(frozen=True)
class ParallaxModel:
    """Per frame, the image shift (dy, dx) in px per px of disparity: ``shift = D * v_k``."""

    per_disparity: tuple[tuple[float, float], ...]

    @classmethod
    def from_caliper(
        cls, positions_mm: Sequence[float], *, baseline_mm: float, axis_angle_deg: float
    ) -> ParallaxModel:
        """From the carriage positions: ``v_k = (c_k - c_0) (sin theta, cos theta) / B``."""
        if not baseline_mm > 0:
            raise ValueError(f"baseline_mm={baseline_mm}; allowed: > 0")
        t = math.radians(axis_angle_deg)
        c0 = positions_mm[0]
        return cls(
            tuple(((c - c0) * math.sin(t) / baseline_mm, (c - c0) * math.cos(t) / baseline_mm)
                  for c in positions_mm)
        )  # fmt: skip

    @classmethod
    def from_registration(
        cls, regs: Sequence[FrameRegistration], *, disparity_px: float
    ) -> ParallaxModel:
        """From global shifts measured where the scene's disparity is ``disparity_px``."""
        if not disparity_px > 0:
            raise ValueError(f"disparity_px={disparity_px}; allowed: > 0 (a finite distance)")
        out = []
        for r in regs:
            if r.shift is None:
                raise ValueError(f"frame {r.index} has no registration ({r.reason})")
            out.append((r.shift[0] / disparity_px, r.shift[1] / disparity_px))
        return cls(tuple(out))

    def shifts(self, disparity_px: float) -> list[tuple[float, float]]:
        """The frames' shifts of a surface at this disparity."""
        return [(disparity_px * a, disparity_px * b) for a, b in self.per_disparity]


def disparity_field(
    disparity: NDArray[np.floating],
    strength: NDArray[np.floating],
    *,
    min_strength: float,
) -> F32:
    """The tile disparity with weak or missing tiles filled from their strong neighbours.

    Returns a ``(tiles_y, tiles_x)`` float32 map without NaN (the median of the strong
    tiles where no neighbour helps).
    """
    d = np.asarray(disparity, dtype=np.float32)
    ok = np.isfinite(d) & (np.asarray(strength) >= min_strength)
    if not ok.any():
        raise ValueError("no tile is strong enough to give a disparity prior")
    fill = float(np.median(d[ok]))
    val = np.where(ok, d, 0.0).astype(np.float32)
    w = ok.astype(np.float32)
    for k in (3, 7, 15):
        num = cv2.boxFilter(val, -1, (k, k), normalize=False)
        den = cv2.boxFilter(w, -1, (k, k), normalize=False)
        val = np.where(ok, val, np.where(den > 0, num / np.maximum(den, 1e-6), 0.0))
        ok = ok | (den > 0)
        w = ok.astype(np.float32)
    out: F32 = np.where(ok, val, fill).astype(np.float32)
    return out


def block_disparity(field: F32, y0: int, y1: int, x0: int, x1: int) -> float:
    """Median disparity of the tiles whose centres (8t + 4) lie in pixels [y0, y1) x [x0, x1)."""
    ty = slice(max(0, (y0 - 4 + 7) // 8), max(1, (y1 - 4 + 7) // 8))
    tx = slice(max(0, (x0 - 4 + 7) // 8), max(1, (x1 - 4 + 7) // 8))
    part = field[ty, tx]
    return float(np.median(part)) if part.size else float(np.median(field))


def block_spread(field: F32, y0: int, y1: int, x0: int, x1: int) -> float:
    """10th-90th percentile range of the tile disparities in a block (as `block_disparity`)."""
    ty = slice(max(0, (y0 - 4 + 7) // 8), max(1, (y1 - 4 + 7) // 8))
    tx = slice(max(0, (x0 - 4 + 7) // 8), max(1, (x1 - 4 + 7) // 8))
    part = field[ty, tx]
    if not part.size:
        return 0.0
    lo, hi = np.percentile(part, [10, 90])
    return float(hi - lo)


def warped_mean(
    frames: Sequence[F32], model: ParallaxModel, disparity_px: F32, *, bayer: str | None
) -> F32:
    """Frames moved back by ``D(p) v_k`` (cubic) and averaged: ``(H, W)`` or ``(H, W, 3)``.

    Bayer frames are demosaiced per colour (bilinear) first. ``disparity_px`` is per pixel.
    """
    from elphel_host.mfsr.fuse import bayer_sites, demosaic_plane

    h, w = frames[0].shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    acc: F32 | None = None
    for frame, (vy, vx) in zip(frames, model.per_disparity, strict=True):
        if bayer is None:
            img = frame[..., None]
        else:
            img = np.stack([demosaic_plane(frame, s) for s in bayer_sites(bayer).values()], -1)
        mapx = (xs - disparity_px * np.float32(vx)).astype(np.float32)
        mapy = (ys - disparity_px * np.float32(vy)).astype(np.float32)
        moved = np.stack(
            [cv2.remap(np.ascontiguousarray(img[..., c]), mapx, mapy, cv2.INTER_CUBIC,
                       borderMode=cv2.BORDER_REFLECT) for c in range(img.shape[2])], -1
        ).astype(np.float32)  # fmt: skip
        acc = moved if acc is None else acc + moved
    assert acc is not None
    out: F32 = (acc / np.float32(len(frames))).astype(np.float32)
    return out[..., 0] if bayer is None else out


def fuse_local(
    frames: Sequence[F32],
    model: ParallaxModel,
    field: F32,
    *,
    scale: int,
    bayer: str | None,
    method: str = "robust",
    block: int = 48,
    margin: int = 16,
    config: RobustConfig = DEFAULT_CONFIG,
    threads: int = 2,
    max_misregistration_px: float = 0.15,
    min_frames: int = 4,
) -> tuple[F32, dict[str, Any]]:
    """Fuse frames block by block, each block registered by its disparity.

    Parameters
    ----------
    frames
        N float32 frames (H, W) of one camera (Bayer mosaics or mono).
    model
        The frames' shift per px of disparity.
    field
        Disparity per tile of this camera's view (``(H/8, W/8)``, no NaN; see
        :func:`disparity_field`).
    scale, bayer, method, config
        As for :func:`elphel_host.mfsr.fuse.fuse_frames`.
    block, margin
        Block side and the overlap fused around it (LR px; even for Bayer).
    max_misregistration_px, min_frames
        A block fuses only the frames whose shift, for the block's disparity spread
        (10th-90th percentile), is wrong by at most ``max_misregistration_px`` at its
        extremes; with fewer than ``min_frames`` such frames the block is the
        parallax-compensated mean (:func:`warped_mean`) up-sampled bicubically instead.

    Returns
    -------
    image, info
        ``(H*S, W*S)`` (or ``(H*S, W*S, 3)`` for Bayer) float32 and per-block details.
    """
    if block % 2 or margin % 2 or block < 16 or margin < 0:
        raise ValueError(f"block={block}, margin={margin}; allowed: even, block >= 16")
    if len(model.per_disparity) != len(frames):
        raise ValueError(
            f"{len(model.per_disparity)} parallax entries for {len(frames)} frames; "
            "allowed: one per frame"
        )
    h, w = frames[0].shape
    starts = [(y, x) for y in range(0, h, block) for x in range(0, w, block)]
    ncol = 1 if bayer is None else 3
    out = np.zeros((h * scale, w * scale, ncol), dtype=np.float32)
    # the largest shift, so every block's frames cover its interior
    reach = int(np.ceil(max(abs(a) + abs(b) for a, b in model.per_disparity) * float(field.max())))
    pad = margin + reach + (reach % 2)

    per_px: F32 = np.asarray(cv2.resize(field, (w, h), interpolation=cv2.INTER_LINEAR), np.float32)
    reach_k = [float(np.hypot(a, b)) for a, b in model.per_disparity]
    fallback: list[F32] = []  # the warped mean, computed once if a block needs it

    def mean_up(ya: int, yb: int, xa: int, xb: int) -> F32:
        if not fallback:
            fallback.append(warped_mean(frames, model, per_px, bayer=bayer))
        part = fallback[0][ya:yb, xa:xb]
        up = cv2.resize(part, None, fx=scale, fy=scale, interpolation=cv2.INTER_CUBIC)
        out_: F32 = np.asarray(up, np.float32).reshape(up.shape[0], up.shape[1], ncol)
        return out_

    def one(start: tuple[int, int]) -> tuple[tuple[int, int], F32, float, int]:
        y, x = start
        y1, x1 = min(y + block, h), min(x + block, w)
        d = block_disparity(field, y, y1, x, x1)
        spread = block_spread(field, y, y1, x, x1)
        ya, xa = max(0, y - pad), max(0, x - pad)
        yb, xb = min(h, y1 + pad), min(w, x1 + pad)
        use = [k for k, r in enumerate(reach_k) if r * spread / 2 <= max_misregistration_px]
        if len(use) < min_frames:
            img = mean_up(ya, yb, xa, xb)
        else:
            crop = [np.ascontiguousarray(frames[k][ya:yb, xa:xb]) for k in use]
            shifts = model.shifts(d)
            regs = [FrameRegistration(i, shifts[k], 1.0, "parallax", True)
                    for i, k in enumerate(use)]  # fmt: skip
            img, _ = fuse_registered(crop, regs, scale=scale, method=method, bayer=bayer,
                                     config=config)  # fmt: skip
            img = img.reshape(img.shape[0], img.shape[1], ncol)
        oy, ox = (y - ya) * scale, (x - xa) * scale
        n_used = len(use) if len(use) >= min_frames else 0
        return start, img[oy : oy + (y1 - y) * scale, ox : ox + (x1 - x) * scale], d, n_used

    if any(
        len([r for r in reach_k if r * block_spread(field, y, min(y + block, h), x,
                                                     min(x + block, w)) / 2
             <= max_misregistration_px]) < min_frames
        for y, x in starts
    ):  # fmt: skip
        mean_up(0, 1, 0, 1)  # compute the shared fallback before the threads need it
    results = parallel_map(one, starts, threads=threads)
    disparities = []
    used = []
    for (y, x), img, d, n in results:
        out[y * scale : y * scale + img.shape[0], x * scale : x * scale + img.shape[1]] = img
        disparities.append(d)
        used.append(n)
    image: F32 = out[..., 0] if bayer is None else out
    return image, {
        "blocks": len(starts),
        "block_px": block,
        "block_disparity_px": [float(np.min(disparities)), float(np.max(disparities))],
        "block_frames": used,
        "blocks_mean_fallback": int(sum(1 for n in used if n == 0)),
    }
