"""What the solve starts from: each camera's corners in each view, and the checks on them.

`Observations` holds, per view and camera, the detected corners (or None: the board was
not found). `check_observations` refuses, with a message that says what to add, the sets
no calibration can come from: a camera with too few views and cameras that share no
view with the rest (a camera whose views are all fronto-parallel is refused by
`initial.initial_guess`, which sees the boards' poses).
"""

from __future__ import annotations

from dataclasses import dataclass

from elphel_host.calibrate.detect import Corners
from elphel_host.calibrate.pattern import Checkerboard
from elphel_host.errors import ElphelError

#: Fewest views of a camera the solve accepts, and fewest it stops warning about.
MIN_VIEWS = 4
ENOUGH_VIEWS = 10


class CalibrationInputError(ElphelError, ValueError):
    """The views cannot give a calibration; the message says what to add or change."""


@dataclass(frozen=True)
class Observations:
    """Corners per view and camera: ``corners[view][camera]`` is `Corners` or None."""

    pattern: Checkerboard
    sizes: tuple[tuple[int, int], ...]  # (width, height) per camera
    corners: tuple[tuple[Corners | None, ...], ...]
    view_names: tuple[str, ...]

    def __post_init__(self) -> None:
        if len(self.view_names) != len(self.corners):
            raise ValueError(f"{len(self.view_names)} view names for {len(self.corners)} views")
        for name, row in zip(self.view_names, self.corners, strict=True):
            if len(row) != len(self.sizes):
                raise ValueError(f"view {name}: {len(row)} cameras; allowed: {len(self.sizes)}")

    @property
    def cameras(self) -> int:
        return len(self.sizes)

    def seen(self, camera: int) -> list[int]:
        """Views in which ``camera`` found the board."""
        return [v for v, row in enumerate(self.corners) if row[camera] is not None]

    def missing(self) -> list[tuple[str, int]]:
        """(view name, camera) of every image where the board was not found."""
        return [
            (name, c)
            for name, row in zip(self.view_names, self.corners, strict=True)
            for c, found in enumerate(row)
            if found is None
        ]

    def subset(self, views: list[int]) -> Observations:
        """The same cameras with only ``views``."""
        return Observations(
            self.pattern,
            self.sizes,
            tuple(self.corners[v] for v in views),
            tuple(self.view_names[v] for v in views),
        )


def connected_groups(obs: Observations) -> list[list[int]]:
    """Cameras grouped by shared views (two cameras that saw the board in one view are linked)."""
    parent = list(range(obs.cameras))

    def root(c: int) -> int:
        while parent[c] != c:
            c = parent[c]
        return c

    for row in obs.corners:
        seen = [c for c, found in enumerate(row) if found is not None]
        for c in seen[1:]:
            parent[root(c)] = root(seen[0])
    groups: dict[int, list[int]] = {}
    for c in range(obs.cameras):
        groups.setdefault(root(c), []).append(c)
    return sorted(groups.values())


def check_observations(obs: Observations) -> list[str]:
    """Raise `CalibrationInputError` on sets no calibration comes from; return warnings."""
    warnings = []
    for c in range(obs.cameras):
        n = len(obs.seen(c))
        if n < MIN_VIEWS:
            raise CalibrationInputError(
                f"camera {c} found the board in {n} view(s); allowed: at least {MIN_VIEWS} "
                f"(about 20 is good): capture more views with the whole board in camera {c}'s image"
            )
        if n < ENOUGH_VIEWS:
            warnings.append(f"camera {c}: only {n} views; {ENOUGH_VIEWS}-30 give a steadier result")
    groups = connected_groups(obs)
    if len(groups) > 1:
        apart = [g for g in groups if 0 not in g]
        names = ", ".join(str(c) for g in apart for c in g)
        raise CalibrationInputError(
            f"camera(s) {names} share no view with camera 0's group {groups[0]}: add views where "
            f"the whole board is seen at once by camera {apart[0][0]} and one of cameras "
            f"{groups[0]}"
        )
    return warnings
