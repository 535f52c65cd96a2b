"""What a guided capture judges: is a view usable, is it new, and what is still missing.

A camera's view of the board is *usable* when the whole board is found, its edges are
sharp (the blurred-corner fit's edge width, `Corners.blur_px`, at most
`CaptureLimits.max_blur_px`) and it covers at least `CaptureLimits.min_area_percent` of
the image. It is *new* when it differs from every view already kept for that camera by
place, size or tilt (`Placement.distance` at least 1). Coverage is counted per camera on
a 16 x 12 grid of cells (views whose corners fell in each cell); the hints name the
ninths of the image no view reached, the tilts with too few views, and, for a rig, the
cameras not linked to camera 0 by a view two of them saw.

The tilt of a board is read from its corners with a guessed lens (focal length the
image's width, no distortion): good to a few degrees, enough to tell a tilted view from
a square-on one.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from elphel_host.calibrate.detect import Corners, eight_bit, grey_image
from elphel_host.calibrate.pattern import Checkerboard

FloatArray = NDArray[np.float64]
CELLS = (16, 12)
#: Tilts (degrees) a set of views should hold, each in at least `VIEWS_PER_TILT` views.
TILT_DEG = 15.0
VIEWS_PER_TILT = 2
#: The four tilts, as (name, which angle, sign) with the angle of `Placement`.
TILTS = (
    ("left edge farther", "turn_deg", -1),
    ("right edge farther", "turn_deg", 1),
    ("top edge farther", "tilt_deg", -1),
    ("bottom edge farther", "tilt_deg", 1),
)
REGIONS = (
    ("top-left", "top", "top-right"),
    ("left", "centre", "right"),
    ("bottom-left", "bottom", "bottom-right"),
)


@dataclass(frozen=True)
class CaptureLimits:
    """When a view is kept: edge width, size, and how far it must differ from the others."""

    max_blur_px: float = 2.0
    min_area_percent: float = 3.0

    def __post_init__(self) -> None:
        if not self.max_blur_px > 0:
            raise ValueError(f"max_blur_px={self.max_blur_px}; allowed: > 0")
        if not 0 < self.min_area_percent < 100:
            raise ValueError(f"min_area_percent={self.min_area_percent}; allowed: 0 < x < 100")


@dataclass(frozen=True)
class Placement:
    """Where a board lies in one image: centre (fractions of the image), area and tilt.

    ``turn_deg`` > 0: the board's right edge is farther from the camera than its left
    (turned about its vertical axis); ``tilt_deg`` > 0: its bottom edge is farther.
    """

    centre: tuple[float, float]
    area_percent: float
    turn_deg: float
    tilt_deg: float

    def distance(self, other: Placement) -> float:
        """How different two placements are: 1 is a step worth a new view."""
        d = np.array(
            [
                (self.centre[0] - other.centre[0]) / 0.15,
                (self.centre[1] - other.centre[1]) / 0.15,
                np.log(self.area_percent / other.area_percent) / np.log(1.5),
                (self.turn_deg - other.turn_deg) / 10.0,
                (self.tilt_deg - other.tilt_deg) / 10.0,
            ]
        )
        return float(np.linalg.norm(d))


@dataclass(frozen=True)
class Seen:
    """One camera's judgement of one view: ``status`` ``ok`` or why not, and what was found.

    ``status`` is one of ``ok``, ``none`` (no board), ``partial``, ``blurred``, ``small``;
    ``reason`` says it for a person.
    """

    status: str
    reason: str
    corners: FloatArray | None = None
    placement: Placement | None = None
    blur_px: float | None = None


def placement(corners: FloatArray, pattern: Checkerboard, size: tuple[int, int]) -> Placement:
    """The board's `Placement` from its corners ``(N, 2)`` in an image of ``size`` (w, h)."""
    w, h = size
    grid = corners.reshape(pattern.rows, pattern.cols, 2)
    outline = np.array([grid[0, 0], grid[0, -1], grid[-1, -1], grid[-1, 0]], dtype=np.float32)
    area = float(cv2.contourArea(outline))
    focal = float(w)
    k = np.array([[focal, 0, (w - 1) / 2], [0, focal, (h - 1) / 2], [0, 0, 1]])
    ok = np.isfinite(corners).all(axis=1)
    found, rvec, _ = cv2.solvePnP(pattern.object_points_mm()[ok], corners[ok], k, None)
    normal = np.array([0.0, 0.0, 1.0])
    if found and np.all(np.isfinite(rvec)):
        normal = cv2.Rodrigues(rvec)[0][:, 2]
    if normal[2] < 0:
        normal = -normal
    centre = np.nanmean(corners, axis=0)
    return Placement(
        (float(centre[0] / w), float(centre[1] / h)),
        100.0 * area / (w * h),
        float(np.degrees(np.arctan2(-normal[0], normal[2]))),
        float(np.degrees(np.arctan2(-normal[1], normal[2]))),
    )


def partly_seen(image: NDArray[np.generic], pattern: Checkerboard, bayer: str | None) -> bool:
    """Whether part of a checkerboard is in an image where the whole board was not found."""
    small = eight_bit(grey_image(image, bayer))
    found, corners, _ = cv2.findChessboardCornersSBWithMeta(small, (3, 3), cv2.CALIB_CB_LARGER)
    return bool(found) and corners is not None and len(corners) < pattern.count


def judge(
    found: Corners | None,
    image: NDArray[np.generic],
    pattern: Checkerboard,
    *,
    bayer: str | None,
    limits: CaptureLimits,
) -> Seen:
    """One camera's view: usable (``ok``) or why not (see `Seen`)."""
    if found is None:
        if partly_seen(image, pattern, bayer):
            return Seen(
                "partial",
                f"partly seen: part of a checkerboard, not the whole {pattern.cols}x"
                f"{pattern.rows} corners with a white margin; move it all into the image",
            )
        return Seen("none", f"no {pattern.cols}x{pattern.rows} board seen")
    h, w = image.shape[:2]
    where = placement(found.pixels, pattern, (w, h))
    blur = float(np.nanmedian(found.blur_px))
    lost = int(np.count_nonzero(~np.isfinite(found.pixels[:, 0])))
    if blur > limits.max_blur_px or lost > pattern.count // 4:
        return Seen(
            "blurred",
            f"blurred: edges {blur:.1f} px wide ({lost} corners lost); allowed: at most "
            f"{limits.max_blur_px:g} px: hold the board still and in focus",
            found.pixels,
            where,
            blur,
        )
    if where.area_percent < limits.min_area_percent:
        return Seen(
            "small",
            f"too small: the board covers {where.area_percent:.1f} % of the image; allowed: "
            f"at least {limits.min_area_percent:g} %: bring it closer",
            found.pixels,
            where,
            blur,
        )
    return Seen("ok", "whole and sharp", found.pixels, where, blur)


def coverage(corner_sets: Sequence[FloatArray], size: tuple[int, int]) -> NDArray[np.int64]:
    """Per cell of `CELLS` (rows, cols): how many views' boards reached it.

    A board reaches the cells its corners fall in and those inside their convex hull.
    """
    nx, ny = CELLS
    w, h = size
    count = np.zeros((ny, nx), dtype=np.int64)
    for corners in corner_sets:
        ok = corners[np.isfinite(corners).all(axis=1)]
        cells = ok * np.array([nx / w, ny / h])
        hit = np.zeros((ny, nx), dtype=np.uint8)
        hull = cv2.convexHull(np.round(cells - 0.5).astype(np.int32))  # cell centres inside
        cv2.fillConvexPoly(hit, hull, 1)
        ix = np.clip(cells[:, 0].astype(int), 0, nx - 1)
        iy = np.clip(cells[:, 1].astype(int), 0, ny - 1)
        hit[iy, ix] = 1
        count += hit
    return count


def empty_regions(count: NDArray[np.int64]) -> list[str]:
    """The ninths of the image (``top-left`` ...) where at most half the cells were reached."""
    rows = np.array_split(np.arange(count.shape[0]), 3)
    cols = np.array_split(np.arange(count.shape[1]), 3)
    out = []
    for r, names in zip(rows, REGIONS, strict=True):
        for c, name in zip(cols, names, strict=True):
            if np.mean(count[np.ix_(r, c)] > 0) <= 0.5:
                out.append(name)
    return out


def missing_tilts(placements: Sequence[Placement]) -> list[str]:
    """The tilts of `TILTS` with fewer than `VIEWS_PER_TILT` views."""
    out = []
    for name, angle, sign in TILTS:
        held = sum(1 for p in placements if sign * getattr(p, angle) >= TILT_DEG)
        if held < VIEWS_PER_TILT:
            out.append(name)
    return out


def unlinked(cameras: int, seen_by: Sequence[Sequence[int]]) -> list[int]:
    """Cameras no chain of shared views links to camera 0 (``seen_by``: per view, who saw it)."""
    linked = {0}
    grew = True
    while grew:
        grew = False
        for view in seen_by:
            if linked & set(view) and not set(view) <= linked:
                linked |= set(view)
                grew = True
    return [c for c in range(cameras) if c not in linked]


def hints(
    counts: Sequence[NDArray[np.int64]],
    placements: Sequence[Placement],
    seen_by: Sequence[Sequence[int]],
) -> list[str]:
    """What the views still lack, for a person holding the board (empty: nothing)."""
    out = []
    for camera, count in enumerate(counts):
        regions = empty_regions(count)
        if regions:
            where = "the image's" if len(counts) == 1 else f"cam{camera}'s"
            out.append(f"put the board in {where} {', '.join(regions)}")
    tilts = missing_tilts(placements)
    if tilts:
        out.append(
            f"add views of the board turned by 20-40 degrees with its {'; its '.join(tilts)} "
            f"(at least {VIEWS_PER_TILT} views each)"
        )
    lost = unlinked(len(counts), seen_by)
    if lost and len(counts) > 1:
        names = ", ".join(f"cam{c}" for c in lost)
        out.append(
            f"{names} share no view with cam0: hold the board farther away so that one of "
            "them and a camera linked to cam0 see it whole at once"
        )
    return out


def text_map(count: NDArray[np.int64], title: str) -> list[str]:
    """A coverage grid as text, two characters a cell: ``..`` none, ``--``, ``++``, ``##`` 3+."""
    marks = np.array(["..", "--", "++", "##"])
    rows = ["".join(marks[np.minimum(row, 3)]) for row in count]
    width = 2 * count.shape[1]
    return [title[:width].ljust(width), *rows]
