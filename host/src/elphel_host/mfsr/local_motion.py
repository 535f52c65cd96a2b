"""Per-pixel motion for bursts of a 3-D scene taken from a moving carriage.

When the carriage moves by ``s`` mm along an axis at angle theta to the sensor rows, a
surface at disparity D (pixels between two cameras one baseline B apart) moves by
``D * s / B`` pixels along that axis: near surfaces move more than far ones, so one
global shift per frame cannot register the frames. Here the motion of frame k is
``shift_k(p) = D(p) * v_k``, with ``v_k`` the frame's shift per pixel of disparity (from
the caliper positions and the axis angle, or from the global registration divided by the
disparity of the registration window) and D(p) the quad's own disparity map, moved into
each camera's view (:func:`camera_view_disparity`).

`fuse_parallax` fuses the frames by shift-and-add: every sample of every frame is put
where the motion model says it was seen on the first frame's grid, up-sampled, and
spread over the four nearest output pixels with bilinear weights; each output pixel is
the weighted mean of the samples that reached it. Output pixels that no sample reached
take the normalised-convolution estimate of a wider Gaussian. A Bayer mosaic's green
gives the detail; red and blue are green plus their smooth difference from it. Each
sample moves by its own disparity, so depth edges, slopes and long carriage travel need
no blocks and no fallback; where a near and a far surface both fit a sample, the near
one, which hides the far one, is taken.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elphel_host.mfsr.bayer import bayer_sites
from elphel_host.mfsr.registration import FrameRegistration
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
        sin, cos = math.sin(t), math.cos(t)
        shifts = (
            ((c - c0) * sin / baseline_mm, (c - c0) * cos / baseline_mm) for c in positions_mm
        )
        return cls(tuple(shifts))

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


def pixel_disparity(field: F32, shape: tuple[int, int]) -> F32:
    """A tile map (tile centres at 8t + 4) interpolated to every pixel of ``shape`` (H, W)."""
    h, w = shape
    out: F32 = np.asarray(cv2.resize(field, (w, h), interpolation=cv2.INTER_LINEAR), np.float32)
    return out


def camera_view_disparity(centre: F32, position: tuple[float, float], *, steps: int = 3) -> F32:
    """The centre view's per-pixel disparity moved into the view of the camera at ``position``.

    A point seen at p by the virtual centre camera is seen by camera i at
    ``p - D * position_i``, so camera i's map is ``D_i(q) = D_c(q + D_i(q) * position_i)``,
    solved by a few fixed-point steps (a shift of up to D/2 px: several pixels on near
    surfaces, which is what puts a depth edge where this camera sees it).
    """
    h, w = centre.shape
    px, py = np.float32(position[0]), np.float32(position[1])
    if px == 0 and py == 0:
        return centre
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    d: NDArray[Any] = centre
    for _ in range(steps):
        rx, ry = xs + d * px, ys + d * py
        d = cv2.remap(centre, rx, ry, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    out: F32 = np.asarray(d, np.float32)
    return out


def _channels(bayer: str | None, h: int, w: int) -> tuple[NDArray[np.int64], int]:
    """Each pixel's output plane (R 0, G 1, B 2 of a Bayer mosaic; 0 for mono) and the count."""
    ch = np.zeros((h, w), np.int64)
    if bayer is None:
        return ch, 1
    for plane, colour in enumerate("RGB"):
        for y, x in bayer_sites(bayer)[colour]:
            ch[y::2, x::2] = plane
    return ch, 3


def fuse_parallax(
    frames: Sequence[NDArray[Any]],
    model: ParallaxModel,
    disparity: F32,
    *,
    scale: int,
    bayer: str | None,
    threads: int = 2,
    band_rows: int = 128,
    min_weight: float = 0.2,
    fixed_point_steps: int = 3,
) -> tuple[F32, dict[str, Any]]:
    """Shift-and-add fusion of a burst whose motion is ``disparity(p) * v_k`` per pixel.

    Parameters
    ----------
    frames
        N frames (H, W) of one camera (Bayer mosaics or mono), any real dtype.
    model
        The frames' shift per px of disparity (frame 0 is the reference: usually 0).
    disparity
        ``(H, W)`` disparity of this camera's view of frame 0, per pixel
        (:func:`pixel_disparity`, :func:`camera_view_disparity`).
    scale
        Up-sampling factor. The output grid is the first frame's, with LR pixel i centred
        at ``scale * i + (scale - 1) / 2`` (as ``cv2.resize`` aligns them).
    bayer
        The mosaic's pattern (``"GRBG"`` ...) or None for mono.
    threads
        Bands of output rows fused in parallel (each owns its rows: no locks).
    band_rows, min_weight
        Rows of a band (LR px); an output pixel whose bilinear weights sum to less than
        ``min_weight`` is filled from wider Gaussian normalised convolutions.
    fixed_point_steps
        Steps of ``r = q + D(r) v_k`` that find where sample q of frame k was seen. They
        start from the largest disparity along q's line of sight (``q + t v_k`` for t over
        the map's range), so that where a near and a far surface both fit, the near one,
        which hides the far one, is found.

    Returns
    -------
    image, info
        ``(H*S, W*S)`` float32 (``(H*S, W*S, 3)`` RGB for Bayer) and details: frames,
        ``filled_fraction`` (output pixels of the mono or green plane filled from wider
        kernels), the largest shift.
    """
    if len(model.per_disparity) != len(frames):
        raise ValueError(
            f"{len(model.per_disparity)} parallax entries for {len(frames)} frames; "
            "allowed: one per frame"
        )
    h, w = frames[0].shape
    if disparity.shape != (h, w):
        raise ValueError(f"disparity map {disparity.shape}, frames {(h, w)}: allowed: the same")
    s = int(scale)
    chan, nc = _channels(bayer, h, w)
    dmap = np.ascontiguousarray(disparity, dtype=np.float32)
    reach_y = max(abs(vy) for vy, _ in model.per_disparity) * float(np.abs(dmap).max())
    splat = _Splat(
        frames=[np.asarray(f) for f in frames],  # read as they are, band by band
        per_disparity=model.per_disparity,
        dmap=dmap,
        chan=chan,
        nc=nc,
        scale=s,
        margin=int(np.ceil(reach_y)) + 2,
        fixed_point_steps=fixed_point_steps,
    )
    bands = [(b, min(b + band_rows, h)) for b in range(0, h, band_rows)]
    parallel_map(splat.band, bands, threads=threads)
    image, filled = _normalised_image(splat, min_weight, mono=bayer is None)
    return image, {
        "fusion": "parallax shift-and-add",
        "frames": len(frames),
        "filled_fraction": round(filled / (h * s * w * s), 6),
        "max_shift_px": round(
            max(float(np.hypot(vy, vx)) for vy, vx in model.per_disparity) * float(dmap.max()), 3
        ),
    }


def _normalised_image(splat: _Splat, min_weight: float, *, mono: bool) -> tuple[F32, int]:
    """The accumulated planes normalised (holes filled); for Bayer, R and B from green."""
    nc, (hs, ws) = splat.nc, splat.num.shape[1:]
    out = np.empty((hs, ws, nc), np.float32)
    detail = nc // 2  # mono: the only plane; Bayer: green
    out[..., detail], filled = _normalise(splat.num[detail], splat.den[detail], min_weight)
    if nc == 3:
        # Red and blue: green's detail plus their difference from green, smoothed over the
        # mosaic's period (each has a quarter of the samples, which a short carriage travel
        # leaves far apart on the output grid; their own detail there is mostly holes).
        sigma = 2.0 * splat.scale
        green = _smooth(splat.num[1], splat.den[1], sigma)
        for c in (0, 2):
            out[..., c] = out[..., 1] + (_smooth(splat.num[c], splat.den[c], sigma) - green)
    image: F32 = out[..., 0] if mono else out
    return image, filled


class _Splat:
    """Bilinear splatting of every frame's samples where frame 0 saw them, band by band.

    Each band of LR rows owns its output rows (no locks); ``num`` and ``den`` gather the
    weighted samples and the weights per colour plane.
    """

    def __init__(
        self,
        *,
        frames: list[NDArray[Any]],
        per_disparity: Sequence[tuple[float, float]],
        dmap: F32,
        chan: NDArray[Any],
        nc: int,
        scale: int,
        margin: int,
        fixed_point_steps: int,
    ) -> None:
        self.frames, self.per_disparity, self.dmap = frames, per_disparity, dmap
        self.chan, self.nc, self.scale, self.margin = chan, nc, scale, margin
        self.fixed_point_steps = fixed_point_steps
        self.d_min, self.d_max = float(dmap.min()), float(dmap.max())
        h, w = dmap.shape
        self.num = np.zeros((nc, h * scale, w * scale), np.float32)
        self.den = np.zeros((nc, h * scale, w * scale), np.float32)

    def _seen_at(self, vy: float, vx: float, ys: F32, xs: F32, rows: tuple[int, int]) -> F32:
        """Disparity where samples (ys, xs) were seen on frame 0: r = q + D(r) v, the nearest."""
        vy32, vx32 = np.float32(vy), np.float32(vx)
        d: NDArray[Any] = _line_max(self.dmap, vy, vx, self.d_min, self.d_max, rows=rows)
        for _ in range(self.fixed_point_steps):
            ry, rx = ys + d * vy32, xs + d * vx32
            d = cv2.remap(self.dmap, rx, ry, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return d

    def band(self, rows: tuple[int, int]) -> None:
        """Splat every frame's rows around ``rows`` into the output rows ``rows`` own."""
        s, (h, w) = self.scale, self.dmap.shape
        b0, b1 = rows[0] * s, rows[1] * s  # the output rows this band owns
        ya, yb = max(0, rows[0] - self.margin), min(h, rows[1] + self.margin)
        ys, xs = np.mgrid[ya:yb, 0:w].astype(np.float32)
        # Bins: the band's output rows and columns with a border of 2 on each side, where
        # samples outside the band land (clipped) and are dropped: no masks, no copies.
        bh, bw = b1 - b0 + 4, w * s + 4
        plane = (self.chan[ya:yb] * (bh * bw)).ravel()
        acc_num = np.zeros(self.nc * bh * bw, np.float64)
        acc_den = np.zeros(self.nc * bh * bw, np.float64)
        index = np.empty((4, plane.size), np.int64)
        weight = np.empty((4, plane.size), np.float64)
        for frame, (vy, vx) in zip(self.frames, self.per_disparity, strict=True):
            d = self._seen_at(vy, vx, ys, xs, (ya, yb))
            uy = (ys + d * np.float32(vy)) * np.float32(s) + np.float32((s - 1) / 2 + 2 - b0)
            ux = (xs + d * np.float32(vx)) * np.float32(s) + np.float32((s - 1) / 2 + 2)
            _bilinear(uy, ux, (bh, bw), plane, index, weight)
            # np.add.at adds every entry, repeated indices too (occlusions, compressions)
            np.add.at(acc_den, index.ravel(), weight.ravel())
            weight *= frame[ya:yb].ravel()
            np.add.at(acc_num, index.ravel(), weight.ravel())
        inner = np.s_[:, 2:-2, 2:-2]
        self.num[:, b0:b1] = acc_num.reshape(self.nc, bh, bw)[inner]
        self.den[:, b0:b1] = acc_den.reshape(self.nc, bh, bw)[inner]


def _bilinear(
    uy: F32,
    ux: F32,
    bins: tuple[int, int],
    plane: NDArray[np.int64],
    index: NDArray[np.int64],
    weight: NDArray[np.float64],
) -> None:
    """The four bins around each point (uy, ux) and their bilinear weights, in place."""
    bh, bw = bins
    y0, x0 = np.floor(uy), np.floor(ux)
    fy, fx = (uy - y0).ravel(), (ux - x0).ravel()
    base = np.clip(y0, 0, bh - 2).astype(np.int64).ravel() * bw
    base += np.clip(x0, 0, bw - 2).astype(np.int64).ravel()
    base += plane
    index[0] = base
    np.add(base, 1, out=index[1])
    np.add(base, bw, out=index[2])
    np.add(base, bw + 1, out=index[3])
    gy, gx = 1 - fy, 1 - fx
    np.multiply(gy, gx, out=weight[0])
    np.multiply(gy, fx, out=weight[1])
    np.multiply(fy, gx, out=weight[2])
    np.multiply(fy, fx, out=weight[3])


def _line_max(
    dmap: F32, vy: float, vx: float, t0: float, t1: float, *, rows: tuple[int, int]
) -> F32:
    """Rows ``rows`` of: the largest of ``dmap`` over ``q + t (vy, vx)``, t in [t0, t1]."""
    steps = int(np.ceil((t1 - t0) * max(abs(vy), abs(vx)))) + 1
    offsets = {(round(t * vy), round(t * vx)) for t in np.linspace(t0, t1, steps)}
    if offsets == {(0, 0)}:
        return dmap[rows[0] : rows[1]]
    oy0, ox0 = min(0, *(o[0] for o in offsets)), min(0, *(o[1] for o in offsets))
    oy1, ox1 = max(0, *(o[0] for o in offsets)), max(0, *(o[1] for o in offsets))
    kernel = np.zeros((oy1 - oy0 + 1, ox1 - ox0 + 1), np.uint8)
    for oy, ox in offsets:
        kernel[oy - oy0, ox - ox0] = 1
    # only the rows the kernel reaches from the wanted ones
    ya, yb = max(0, rows[0] + oy0), min(dmap.shape[0], rows[1] + oy1)
    # cv2.dilate: dst(q) = max of src(q + o - anchor) over the kernel's set elements o
    out = cv2.dilate(dmap[ya:yb], kernel, anchor=(-ox0, -oy0), borderType=cv2.BORDER_REPLICATE)
    return np.asarray(out[rows[0] - ya : rows[1] - ya], np.float32)


def _blurred(num: F32, den: F32, sigma: float) -> tuple[NDArray[Any], NDArray[Any]]:
    """Both sums of a normalised convolution with a Gaussian of ``sigma`` output px."""
    n = cv2.GaussianBlur(num, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    d = cv2.GaussianBlur(den, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    return n, d


def _smooth(num: F32, den: F32, sigma: float) -> F32:
    n, d = _blurred(num, den, sigma)
    return np.asarray(n / np.maximum(d, np.float32(1e-6)), np.float32)


def _normalise(num: F32, den: F32, min_weight: float) -> tuple[F32, int]:
    """``num / den`` where ``den >= min_weight``; elsewhere wider normalised convolutions.

    Gaussians of 0.5, 1, 2, ... output px, each filling what the narrower ones left, until
    every pixel has a value. Returns the image and how many pixels were filled.
    """
    ok = den >= min_weight
    out: F32 = np.where(ok, num / np.maximum(den, np.float32(1e-12)), 0).astype(np.float32)
    holes = int(np.count_nonzero(~ok))
    if holes == 0:
        return out, 0
    if not den.any():
        raise ValueError("no sample reached the output grid")
    sigma = 0.5
    while not ok.all():
        n, d = _blurred(num, den, sigma)
        now = ~ok & (d >= min_weight * 1e-3)
        out[now] = n[now] / d[now]
        ok |= now
        sigma *= 2
    return out, holes
