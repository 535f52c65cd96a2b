"""Cloud-to-cloud distances, as CloudCompare computes them by default.

Each point of the compared cloud is given the distance to its nearest point of the
reference cloud (a KD-tree from SciPy, ``scipy.spatial.cKDTree``); the statistics are
taken over those distances. Both directions are reported: compared -> reference says how
far the measured points are from the truth (accuracy), reference -> compared how much of
the truth the measurement covers (completeness). With ``max_distance_mm`` the points
farther than that are left out of the statistics and counted as ``beyond``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from elphel_host.cloud.ply import PointCloud
from elphel_host.errors import InputFormatError

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class DistanceStats:
    """Statistics of one direction's nearest-neighbour distances (millimetres).

    Attributes
    ----------
    points
        Points whose distance entered the statistics.
    beyond
        Points farther than the maximum distance (left out); 0 without one.
    mean_mm, std_mm, median_mm, p95_mm, max_mm
        Of the distances that entered (NaN when none did).
    """

    points: int
    beyond: int
    mean_mm: float
    std_mm: float
    median_mm: float
    p95_mm: float
    max_mm: float

    def to_json(self) -> dict[str, float | int | None]:
        return {
            k: (None if isinstance(v, float) and not np.isfinite(v) else v)
            for k, v in asdict(self).items()
        }


def distance_stats(
    distances: NDArray[np.floating], *, max_distance_mm: float | None = None
) -> DistanceStats:
    """Mean, standard deviation, median, 95th percentile and max of ``distances``."""
    d = np.asarray(distances, dtype=np.float64).ravel()
    beyond = 0
    if max_distance_mm is not None:
        keep = d <= max_distance_mm
        beyond = int(d.size - np.count_nonzero(keep))
        d = d[keep]
    if d.size == 0:
        nan = float("nan")
        return DistanceStats(0, beyond, nan, nan, nan, nan, nan)
    return DistanceStats(
        points=int(d.size),
        beyond=beyond,
        mean_mm=float(d.mean()),
        std_mm=float(d.std()),
        median_mm=float(np.median(d)),
        p95_mm=float(np.percentile(d, 95)),
        max_mm=float(d.max()),
    )


def nearest_distances(
    compared: NDArray[np.floating], reference: NDArray[np.floating], *, workers: int = 1
) -> F64:
    """Distance from each compared point ``(N, 3)`` to its nearest reference point ``(M, 3)``."""
    a = np.asarray(compared, dtype=np.float64)
    b = np.asarray(reference, dtype=np.float64)
    for name, pts in (("compared", a), ("reference", b)):
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise InputFormatError(f"{name} points must have shape (N, 3), got {pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise InputFormatError(f"{name} cloud has non-finite coordinates")
    if b.shape[0] == 0:
        raise InputFormatError("reference cloud is empty: no nearest point to measure to")
    if a.shape[0] == 0:
        return np.zeros(0)
    dist, _ = cKDTree(b).query(a, k=1, workers=workers)
    out: F64 = np.asarray(dist, dtype=np.float64)
    return out


@dataclass(frozen=True, eq=False)
class CloudComparison:
    """Both directions of a cloud-to-cloud comparison.

    Attributes
    ----------
    forward
        Compared -> reference (each compared point to its nearest reference point).
    backward
        Reference -> compared.
    distances_mm
        The forward distance of every compared point (NaN-free), for colouring.
    max_distance_mm
        The cut-off used, or None.
    """

    forward: DistanceStats
    backward: DistanceStats
    distances_mm: F64
    max_distance_mm: float | None

    def to_json(self) -> dict[str, object]:
        return {
            "compared_to_reference": self.forward.to_json(),
            "reference_to_compared": self.backward.to_json(),
            "max_distance_mm": self.max_distance_mm,
        }


def compare_clouds(
    compared: PointCloud,
    reference: PointCloud,
    *,
    max_distance_mm: float | None = None,
    workers: int = 1,
) -> CloudComparison:
    """Cloud-to-cloud distances of ``compared`` against ``reference``, both directions.

    Parameters
    ----------
    compared, reference
        The clouds (millimetres).
    max_distance_mm
        Distances above it are left out of the statistics and counted (None = keep all).
    workers
        Threads for the KD-tree queries.
    """
    if max_distance_mm is not None and not max_distance_mm > 0:
        raise InputFormatError(f"max_distance_mm={max_distance_mm}; allowed: > 0")
    if len(compared) == 0:
        raise InputFormatError("compared cloud is empty")
    fwd = nearest_distances(compared.xyz, reference.xyz, workers=workers)
    bwd = nearest_distances(reference.xyz, compared.xyz, workers=workers)
    return CloudComparison(
        forward=distance_stats(fwd, max_distance_mm=max_distance_mm),
        backward=distance_stats(bwd, max_distance_mm=max_distance_mm),
        distances_mm=fwd,
        max_distance_mm=max_distance_mm,
    )
