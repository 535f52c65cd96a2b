"""Bayer mosaics: the luminance registration sees, colour sites, planes, a bilinear demosaic."""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]
Plane = tuple[list[F32], list[tuple[float, float]]]


def bayer_luma(mosaic: F32) -> F32:
    """2x2-cell mean: a half-resolution luminance for registration."""
    h, w = mosaic.shape
    a = mosaic[: h // 2 * 2, : w // 2 * 2]
    return np.asarray(a.reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3)), dtype=np.float32)


def bayer_sites(bayer: str) -> dict[str, list[tuple[int, int]]]:
    """(row, column) offsets in the 2x2 cell of each colour (R, G, B) of a pattern."""
    out: dict[str, list[tuple[int, int]]] = {"R": [], "G": [], "B": []}
    for idx, c in enumerate(bayer):
        out[c].append((idx // 2, idx % 2))
    return out


def site_shifts(
    shifts: Sequence[tuple[float, float]], sites: list[tuple[int, int]]
) -> list[tuple[float, float]]:
    """Each frame's shift seen by each of its colour sites, in plane px (frame-major).

    A site at (oy, ox) of a frame shifted by s sees the full-resolution grid at
    ``(o + s - 0.5) / 2`` plane px.
    """
    return [((oy + s[0] - 0.5) / 2, (ox + s[1] - 0.5) / 2) for s in shifts for oy, ox in sites]


def frame_shifts(
    plane_shifts: Sequence[tuple[float, float]], sites: list[tuple[int, int]]
) -> list[tuple[float, float]]:
    """The frames' shifts (full-resolution px) from a plane's, the inverse of `site_shifts`.

    A frame with several sites of the colour (green) gets the mean of theirs.
    """
    n = len(sites)
    if len(plane_shifts) % n:
        raise ValueError(f"{len(plane_shifts)} plane shifts; allowed: a multiple of {n} sites")
    out = []
    for k in range(len(plane_shifts) // n):
        per = [
            (2 * p[0] - oy + 0.5, 2 * p[1] - ox + 0.5)
            for p, (oy, ox) in zip(plane_shifts[k * n : (k + 1) * n], sites, strict=True)
        ]
        out.append((float(np.mean([a for a, _ in per])), float(np.mean([b for _, b in per]))))
    return out


def colour_planes(
    frames: Sequence[F32], shifts: Sequence[tuple[float, float]], bayer: str
) -> list[Plane]:
    """Each colour's samples (R, G, B) as frames of half size with their shifts.

    Both green sites make frames of one green plane; shifts as `site_shifts` gives them.
    """
    planes: list[Plane] = []
    for sites in bayer_sites(bayer).values():
        pf = [np.ascontiguousarray(f[oy::2, ox::2]) for f in frames for oy, ox in sites]
        planes.append((pf, site_shifts(shifts, sites)))
    return planes


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
