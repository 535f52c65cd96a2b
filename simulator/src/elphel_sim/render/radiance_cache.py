"""The cache of `elphel_sim.render.radiance.render_strips`: recent frames' radiance.

A full frame's area-integrated radiance costs seconds of CPU; a frame of a still scene
seen again from the same pose and window is the same array, so `render_strips` keeps
recent ones here (the key is made there) and the noise is drawn for every frame anew.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Hashable

from elphel_sim.world import FloatArray, Plane

_Entry = tuple[tuple[Plane, ...], FloatArray]  # the planes keyed by identity, the radiance


class RadianceCache:
    """Recent results of `render_strips`, bounded by bytes, least recently used out first.

    An entry is keyed by everything the radiance depends on, taken when the frame is
    rendered: the scene's planes (by identity, in order; the entry holds them so that their
    ids cannot be reused by other planes) and background, the intrinsics, the pose's
    position and rotation, the window, and the strip times. When no plane moves (every
    ``velocity_mm_s`` is zero) and the times are finite the radiance does not depend on
    time, so then only the number of strips counts; with a moving plane the times
    themselves are part of the key. Replacing or adding a plane, changing the background,
    moving the camera (the carriage) or the window therefore misses. Changing a texture's
    array in place is not seen (the filtered-texture cache does not see it either).

    Entries are read-only arrays (``render_strips`` hands out read-only views of them).
    The cache holds at most ``max_bytes`` of arrays, but always its newest entry. Safe to
    use from several threads; two threads missing the same key at once both render.

    Parameters
    ----------
    max_bytes
        Bound of the arrays held, in bytes.
    """

    def __init__(self, max_bytes: int) -> None:
        if max_bytes < 0:
            raise ValueError(f"max_bytes={max_bytes}; allowed: >= 0")
        self.max_bytes = max_bytes
        self.hits = 0
        self.misses = 0
        self._lock = threading.Lock()
        self._entries: OrderedDict[Hashable, _Entry] = OrderedDict()
        self._nbytes = 0

    def __len__(self) -> int:
        with self._lock:
            return len(self._entries)

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays held."""
        with self._lock:
            return self._nbytes

    def clear(self) -> None:
        """Drop every entry (the hit and miss counts stay)."""
        with self._lock:
            self._entries.clear()
            self._nbytes = 0

    def get(self, key: Hashable) -> FloatArray | None:
        """The read-only radiance stored under ``key``, or None."""
        with self._lock:
            entry = self._entries.get(key)
            if entry is None:
                self.misses += 1
                return None
            self._entries.move_to_end(key)
            self.hits += 1
            return entry[1]

    def put(self, key: Hashable, planes: tuple[Plane, ...], radiance: FloatArray) -> None:
        """Store ``radiance`` (made read-only) under ``key``, holding on to ``planes``."""
        radiance.flags.writeable = False
        with self._lock:
            old = self._entries.pop(key, None)
            if old is not None:
                self._nbytes -= old[1].nbytes
            self._entries[key] = (planes, radiance)
            self._nbytes += radiance.nbytes
            while self._nbytes > self.max_bytes and len(self._entries) > 1:
                _, (_, evicted) = self._entries.popitem(last=False)
                self._nbytes -= evicted.nbytes


#: The cache `render_strips` uses by default: two full MT9P006 frames (115 MiB each).
RADIANCE_CACHE = RadianceCache(max_bytes=256 * 1024 * 1024)
