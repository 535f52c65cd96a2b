"""The cache of `elphel_sim.render.radiance.render_strips`: recent frames' radiance.

A full frame's area-integrated radiance costs seconds of CPU; a frame of a still scene
seen again from the same pose and window is the same array, so `render_strips` keeps
recent ones here (the key is made there) and the noise is drawn for every frame anew.
"""

from __future__ import annotations

import threading
import weakref
from collections import OrderedDict
from collections.abc import Hashable

from elphel_sim.world import FloatArray, Plane

# The planes keyed by identity (held weakly), the radiance.
_Entry = tuple[tuple[weakref.ref[Plane], ...], FloatArray]


class RadianceCache:
    """Recent results of `render_strips`, bounded by bytes, least recently used out first.

    An entry is keyed by everything the radiance depends on, taken when the frame is
    rendered: the scene's planes (by identity, in order) and background, the intrinsics,
    the pose's position and rotation, the window, and the strip times. When no plane
    moves (every ``velocity_mm_s`` is zero) and the times are finite the radiance does not
    depend on time, so then only the number of strips counts; with a moving plane the
    times themselves are part of the key. Replacing or adding a plane, changing the background,
    moving the camera (the carriage) or the window therefore misses. Changing a texture's
    array in place is not seen (the filtered-texture cache does not see it either).

    The planes are held weakly: the cache never keeps a scene alive (its textures and
    their filtered copies are far larger than a small window's radiance). An entry whose
    planes are gone is dropped at the next `put`, and is never a hit, even for a new
    plane that was given a gone plane's id.

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
        self._planes_gone = False  # set when a plane an entry holds is collected

    def _plane_gone(self, _: weakref.ref[Plane]) -> None:
        # Called by the garbage collector, maybe with the lock held: only raise a flag.
        self._planes_gone = True

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
            if entry is None or not _alive(entry):
                self.misses += 1
                return None
            self._entries.move_to_end(key)
            self.hits += 1
            return entry[1]

    def put(self, key: Hashable, planes: tuple[Plane, ...], radiance: FloatArray) -> None:
        """Store ``radiance`` (made read-only) under ``key``, for as long as ``planes`` live."""
        radiance.flags.writeable = False
        refs = tuple(weakref.ref(plane, self._plane_gone) for plane in planes)
        with self._lock:
            if self._planes_gone:
                self._planes_gone = False
                self._drop_dead()
            old = self._entries.pop(key, None)
            if old is not None:
                self._nbytes -= old[1].nbytes
            self._entries[key] = (refs, radiance)
            self._nbytes += radiance.nbytes
            while self._nbytes > self.max_bytes and len(self._entries) > 1:
                _, (_, evicted) = self._entries.popitem(last=False)
                self._nbytes -= evicted.nbytes

    def _drop_dead(self) -> None:
        """Drop the entries whose planes are gone (lock held)."""
        for key in [k for k, entry in self._entries.items() if not _alive(entry)]:
            self._nbytes -= self._entries.pop(key)[1].nbytes


def _alive(entry: _Entry) -> bool:
    """Whether every plane of an entry still exists."""
    return all(ref() is not None for ref in entry[0])


#: The cache `render_strips` uses by default: two full MT9P006 frames (115 MiB each).
RADIANCE_CACHE = RadianceCache(max_bytes=256 * 1024 * 1024)
