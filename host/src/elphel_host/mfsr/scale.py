"""The up-sampling factor of a fusion: its allowed range, named once, and its check.

A fusion (``elphel mfsr``, ``elphel burst capture --fuse``) takes an integer factor
1..:data:`MAX_SCALE`; a burst plan needs at least 2 (a x1 plan has no sub-pixel phases);
the reconstruction kernels take any factor >= 1 (a Bayer colour plane is solved at twice
the burst's factor). Each caller states its bounds; the message says them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from elphel_host.errors import ScaleError

MIN_SCALE = 1
MAX_SCALE = 8


def allowed_scales(*, minimum: int = MIN_SCALE, maximum: int | None = MAX_SCALE) -> str:
    """What a scale check allows, in words: ``an integer 1..8`` or ``an integer >= 1``."""
    return f"an integer {minimum}..{maximum}" if maximum is not None else f"an integer >= {minimum}"


def check_scale(scale: Any, *, minimum: int = MIN_SCALE, maximum: int | None = MAX_SCALE) -> int:
    """``scale`` as an int if it is an integer in ``minimum..maximum`` (no upper bound: None).

    Raises
    ------
    ScaleError
        ``scale={value!r}; allowed: an integer 1..8`` (with the bounds given).
    """
    ok = isinstance(scale, int | np.integer) and not isinstance(scale, bool)
    if ok and minimum <= scale and (maximum is None or scale <= maximum):
        return int(scale)
    raise ScaleError(scale, allowed_scales(minimum=minimum, maximum=maximum))
