"""Guided capture of checkerboard views into a views directory, resumable.

`capture_views` takes a view (one frame of one sensor port, or a trigger-synchronised
quad set through `elphel_host.tp.capture.capture_quad`), finds the board in every
camera's image, judges it (`elphel_host.calibrate.guide`) and keeps the view as the
next ``viewNNN.tif`` (one camera) or ``viewNNN/`` (a quad directory) when at least one
camera sees the board whole, sharp, large enough and in a place or tilt none of its
kept views has; otherwise it says why not. Each attempt is reported to a callback with
the coverage and the hints, for the command line to show.

What was kept is recorded in ``VIEWS_DIR/capture/capture.json`` (the pattern, the
image size and every view's corners) and drawn in ``VIEWS_DIR/capture/coverage.png``;
neither is a view, so `elphel calibrate solve` reads the directory as it is. Running
again on the same directory continues it: views already there count, views added or
removed by hand are noticed (a view not in capture.json is searched for the board).
"""

from __future__ import annotations

import json
import re
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from elphel_host import strict_json
from elphel_host.calibrate.detect import detect
from elphel_host.calibrate.guide import (
    CaptureLimits,
    Placement,
    Seen,
    coverage,
    hints,
    judge,
)
from elphel_host.calibrate.pattern import Checkerboard
from elphel_host.calibrate.pictures import side_by_side
from elphel_host.calibrate.views import view_images, view_sources
from elphel_host.camera.protocol import CameraInterface
from elphel_host.errors import ElphelError
from elphel_host.fileio import write_atomic
from elphel_host.preview import map_picture, save_png
from elphel_host.tp.capture import capture_quad

FloatArray = NDArray[np.float64]
STATE_DIR = "capture"
STATE_FILE = "capture.json"
COVERAGE_PNG = "coverage.png"
_VIEW_NAME = re.compile(r"^view(\d+)(\.tif)?$")


class CaptureSessionError(ElphelError, ValueError):
    """A views directory that this capture cannot continue; the message says why."""


class ViewSource(Protocol):
    """Where views come from: one camera (``cameras`` 1) or a quad (4)."""

    cameras: int

    def take(self, pending: Path) -> tuple[list[NDArray[np.generic]], str | None]:
        """Take a view into ``pending``; its images and Bayer pattern."""
        ...

    def name(self, index: int) -> str:
        """The file or directory name of view ``index``."""
        ...


@dataclass
class SingleCamera:
    """Frames of one sensor port, each kept as the daemon's TIFF (metadata included)."""

    camera: CameraInterface
    port: int = 0
    cameras: int = 1

    def take(self, pending: Path) -> tuple[list[NDArray[np.generic]], str | None]:
        frame = self.camera.capture(self.port)
        write_atomic(pending, frame.tiff)
        bayer = frame.metadata.get("bayer")
        return [frame.image], bayer if isinstance(bayer, str) else None

    def name(self, index: int) -> str:
        return f"view{index:03d}.tif"


@dataclass
class QuadCamera:
    """Trigger-synchronised sets of four ports, each kept as a quad directory."""

    camera: CameraInterface
    timeout_s: float = 60.0
    cameras: int = 4
    trigger_period_ms: float | None = None  # None: chosen at the first set (capture_quad)

    def take(self, pending: Path) -> tuple[list[NDArray[np.generic]], str | None]:
        got = capture_quad(
            self.camera,
            pending,
            force=True,
            timeout_s=self.timeout_s,
            trigger_period_ms=self.trigger_period_ms,
        )
        self.trigger_period_ms = got.trigger_period_ms  # the next sets: no fetch timed
        return view_images(pending, quad=True)

    def name(self, index: int) -> str:
        return f"view{index:03d}"


@dataclass(frozen=True)
class KeptView:
    """A view in the directory: its name and per camera the board's corners (or None)."""

    name: str
    corners: tuple[FloatArray | None, ...]
    placements: tuple[Placement | None, ...]

    @property
    def seen_by(self) -> list[int]:
        return [c for c, corners in enumerate(self.corners) if corners is not None]


@dataclass
class CaptureSession:
    """A views directory being filled: its pattern, cameras, image size and kept views."""

    root: Path
    pattern: Checkerboard
    cameras: int
    size: tuple[int, int] | None = None
    views: list[KeptView] = field(default_factory=list)

    @property
    def state_dir(self) -> Path:
        return self.root / STATE_DIR

    def counts(self) -> list[NDArray[np.int64]]:
        """Per camera the coverage grid (`elphel_host.calibrate.guide.coverage`)."""
        size = self.size or (1, 1)
        return [
            coverage([c for v in self.views if (c := v.corners[cam]) is not None], size)
            for cam in range(self.cameras)
        ]

    def hints(self) -> list[str]:
        """What the kept views still lack (`elphel_host.calibrate.guide.hints`)."""
        # a view's tilt as its first camera that saw the board well saw it
        placements = [next(p for p in v.placements if p) for v in self.views if any(v.placements)]
        return hints(self.counts(), placements, [v.seen_by for v in self.views])

    def next_index(self) -> int:
        taken = [int(m.group(1)) for v in self.views if (m := _VIEW_NAME.match(v.name))]
        return max(taken, default=-1) + 1

    def save(self) -> Path:
        """Write capture.json and coverage.png; the PNG's path."""
        self.state_dir.mkdir(parents=True, exist_ok=True)
        write_atomic(
            self.state_dir / STATE_FILE,
            (strict_json.dumps(self.to_json(), what="the capture state") + "\n").encode(),
        )
        return write_coverage(self, self.state_dir / COVERAGE_PNG)

    def to_json(self) -> dict[str, Any]:
        return {
            "version": 1,
            "pattern": self.pattern.spec,
            "cameras": self.cameras,
            "size": None if self.size is None else list(self.size),
            "views": [_view_json(v) for v in self.views],
        }


def _view_json(view: KeptView) -> dict[str, Any]:
    return {
        "name": view.name,
        "corners": [
            None if c is None else np.round(np.nan_to_num(c, nan=-1.0), 3).tolist()
            for c in view.corners
        ],
        "placements": [None if p is None else _placement_json(p) for p in view.placements],
    }


def _placement_json(p: Placement) -> dict[str, Any]:
    return {
        "centre": list(p.centre),
        "area_percent": p.area_percent,
        "turn_deg": p.turn_deg,
        "tilt_deg": p.tilt_deg,
    }


def _view_from_json(data: dict[str, Any]) -> KeptView:
    corners = tuple(
        None if c is None else np.where(np.asarray(c) < 0, np.nan, np.asarray(c, dtype=float))
        for c in data["corners"]
    )
    placements = tuple(
        None
        if p is None
        else Placement(tuple(p["centre"]), p["area_percent"], p["turn_deg"], p["tilt_deg"])
        for p in data["placements"]
    )
    return KeptView(str(data["name"]), corners, placements)


def write_coverage(session: CaptureSession, path: Path) -> Path:
    """coverage.png: per camera the views that reached each cell, with its colour bar."""
    counts = session.counts()
    hi = max(1.0, *(float(c.max()) for c in counts))
    tiles = []
    for cam, count in enumerate(counts):
        seen = sum(1 for v in session.views if v.corners[cam] is not None)
        title = f"cam{cam}: views per cell ({seen} views; dark: none yet)"
        tiles.append(
            map_picture(count.astype(np.float64), unit="views", title=title, lo=0.0, hi=hi, cell=30)
        )
    return save_png(side_by_side(tiles), path)


def open_session(root: str | Path, pattern: Checkerboard, *, cameras: int) -> CaptureSession:
    """The session of a views directory: new, or continued from capture.json and its views.

    Views on disk that capture.json does not list are searched for the board; views it
    lists that are gone are forgotten.

    Raises
    ------
    CaptureSessionError
        capture.json names another pattern or another number of cameras, or the
        directory holds views of the other kind (quad directories for one camera...).
    """
    session = CaptureSession(Path(root), pattern, cameras)
    state = session.state_dir / STATE_FILE
    known: dict[str, KeptView] = {}
    if state.is_file():
        data = _read_state(state)
        if data.get("pattern") != pattern.spec or data.get("cameras") != cameras:
            raise CaptureSessionError(
                f"{root} was captured with --pattern {data.get('pattern')} and "
                f"{data.get('cameras')} camera(s); allowed: the same to continue it (or "
                "another --out)"
            )
        session.size = None if data.get("size") is None else tuple(data["size"])
        try:
            known = {v["name"]: _view_from_json(v) for v in data.get("views", [])}
        except (KeyError, TypeError, ValueError) as e:
            raise CaptureSessionError(
                f"{state}: a view's entry is not readable ({type(e).__name__}: {e}); "
                "remove the file to search the views again"
            ) from e
    for path in _views_on_disk(session.root, cameras):
        view = known.get(path.name)
        if view is None:
            images, bayer = view_images(path, quad=cameras > 1)
            view = _judged_view(path.name, images, bayer, session, CaptureLimits())[0]
        session.views.append(view)
    return session


def _read_state(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise CaptureSessionError(
            f"{path}: not a capture state ({e}); remove it to search the views again"
        ) from e
    if not isinstance(data, dict):
        raise CaptureSessionError(f"{path}: not a JSON object; remove it to search the views again")
    return data


def _views_on_disk(root: Path, cameras: int) -> list[Path]:
    if not root.is_dir() or not any(root.iterdir()):
        return []
    try:
        paths, quad = view_sources(root)
    except ElphelError:
        return []  # nothing but the capture's own files yet
    if quad != (cameras > 1):
        kind = "quad directories" if quad else "image files of one camera"
        raise CaptureSessionError(
            f"{root} holds {kind}; allowed: views of {cameras} camera(s) as this capture "
            "takes them (give --quad for a quad, or another --out)"
        )
    return paths


@dataclass(frozen=True)
class Attempt:
    """One view taken: kept (its name) or not, and each camera's judgement."""

    number: int
    kept: str | None
    seen: tuple[Seen, ...]
    reason: str


def _judged_view(
    name: str,
    images: list[NDArray[np.generic]],
    bayer: str | None,
    session: CaptureSession,
    limits: CaptureLimits,
) -> tuple[KeptView, tuple[Seen, ...]]:
    """A view's cameras judged; the view as it would be kept (usable cameras only)."""
    size = (int(images[0].shape[1]), int(images[0].shape[0]))
    if session.size is None:
        session.size = size
    elif size != session.size:
        raise CaptureSessionError(
            f"{name}: images of {size[0]}x{size[1]}; allowed: {session.size[0]}x"
            f"{session.size[1]} as the directory's other views (or another --out)"
        )
    seen = tuple(
        judge(
            detect(np.asarray(im), session.pattern, bayer=bayer),
            np.asarray(im),
            session.pattern,
            bayer=bayer,
            limits=limits,
        )
        for im in images
    )
    usable = [s if s.status == "ok" else None for s in seen]
    view = KeptView(
        name,
        tuple(None if s is None else s.corners for s in usable),
        tuple(None if s is None else s.placement for s in usable),
    )
    return view, seen


def _novelty(view: KeptView, seen: tuple[Seen, ...], session: CaptureSession) -> str | None:
    """None when some camera sees the board where none of its kept views had it; else why."""
    closest: tuple[float, str] = (np.inf, "")
    for cam, where in enumerate(view.placements):
        if where is None:
            continue
        others = [(where.distance(p), v.name) for v in session.views if (p := v.placements[cam])]
        nearest = min(others, default=(np.inf, ""))
        if nearest[0] >= 1.0:
            return None
        closest = min(closest, nearest)
    if not np.isfinite(closest[0]):
        if len(seen) == 1:
            return seen[0].reason
        return "no camera sees the whole board sharp and large enough"
    return (
        f"like {closest[1]} (same place, size and tilt): move the board to a new place or "
        "tilt it differently"
    )


def take_view(
    source: ViewSource, session: CaptureSession, limits: CaptureLimits, number: int
) -> Attempt:
    """Take one view; keep it in the directory when it is usable and new (see the module)."""
    pending = session.state_dir / ("pending" if source.cameras > 1 else "pending.tif")
    session.state_dir.mkdir(parents=True, exist_ok=True)
    try:
        images, bayer = source.take(pending)
        name = source.name(session.next_index())
        view, seen = _judged_view(name, images, bayer, session, limits)
        why = _novelty(view, seen, session)
        if why is None:
            pending.rename(session.root / name)
            session.views.append(view)
            session.save()
            return Attempt(number, name, seen, "kept")
        return Attempt(number, None, seen, why)
    finally:
        if pending.is_dir():
            shutil.rmtree(pending)
        elif pending.exists():
            pending.unlink()


def capture_views(
    source: ViewSource,
    session: CaptureSession,
    *,
    views: int,
    limits: CaptureLimits | None = None,
    attempts: int | None = None,
    interval_s: float = 0.5,
    before: Callable[[int], object] | None = None,
    report: Callable[[Attempt, CaptureSession], None] | None = None,
) -> list[Attempt]:
    """Take views until the directory holds ``views`` of them (or ``attempts`` were made).

    Parameters
    ----------
    source
        `SingleCamera` or `QuadCamera`.
    session
        The directory's session (`open_session`); its views count towards ``views``.
    views
        How many views the directory should hold.
    limits
        When a camera's view is usable (default `CaptureLimits`).
    attempts
        Stop after this many views taken (None: only at ``views``).
    interval_s
        Pause between attempts, for the person moving the board (not before the first,
        and not when ``before`` is given).
    before
        Called with the attempt's number before each attempt (a script posing the board).
    report
        Called after each attempt with its outcome and the session.

    Returns
    -------
    list of Attempt
    """
    limits = limits or CaptureLimits()
    done: list[Attempt] = []
    while len(session.views) < views and (attempts is None or len(done) < attempts):
        if before is not None:
            before(len(done))
        elif done:
            time.sleep(interval_s)
        attempt = take_view(source, session, limits, len(done) + 1)
        done.append(attempt)
        if report is not None:
            report(attempt, session)
    if not session.state_dir.joinpath(STATE_FILE).is_file():
        session.save()
    return done
