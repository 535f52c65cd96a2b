"""Run independent pieces of MFSR work on every core.

NumPy's element-wise work, SciPy's FFTs and OpenCV release the GIL on large arrays, so
plain threads run them truly in parallel: one frame, alias or row band per thread.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

_T = TypeVar("_T")

THREADS = min(os.cpu_count() or 1, 8)


def parallel_map(fn: Callable[[Any], _T], items: Sequence[Any]) -> list[_T]:
    """``fn`` over ``items`` on every core, results in order."""
    if THREADS == 1 or len(items) < 2:
        return [fn(item) for item in items]
    with ThreadPoolExecutor(max_workers=min(THREADS, len(items))) as pool:
        return list(pool.map(fn, items))
