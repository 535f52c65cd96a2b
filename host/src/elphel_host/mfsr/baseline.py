"""``baseline``: the published direct method, implemented as published.

Every frame is up-sampled to the output size with ``cv2.resize`` (bicubic), registered to
the up-sampled first frame with ``cv2.findTransformECC`` (translation), warped onto it and
the stack is reduced by a per-pixel median. It keeps all N up-sampled frames in memory,
as the method does; use it for comparisons, not for large bursts.

Two details the publication leaves open are fixed here: ECC starts from the identity and,
if it fails to converge, once more from phase correlation of the up-sampled frames; frames
that still fail are excluded and reported. Warping is bicubic with mirrored borders.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elphel_host.mfsr.registration import phase_correlation_shift
from elphel_host.mfsr.scale import check_scale

F32 = NDArray[np.float32]

_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-3)


def _upsampled(frame: F32, size: tuple[int, int]) -> F32:
    """``frame`` resized bicubically to ``size`` (width, height)."""
    up = cv2.resize(np.asarray(frame, np.float32), size, interpolation=cv2.INTER_CUBIC)
    return np.asarray(up, dtype=np.float32)


def _ecc_warp(ref: F32, up: F32) -> NDArray[np.float32] | None:
    """ECC translation of ``up`` onto ``ref`` from identity, else from phase correlation."""
    for init in ((0.0, 0.0), None):
        if init is None:
            init = phase_correlation_shift(ref, up)
        m = np.array([[1.0, 0.0, -init[1]], [0.0, 1.0, -init[0]]], dtype=np.float32)
        try:
            _, warp = cv2.findTransformECC(  # type: ignore[call-overload]
                ref, up, m, cv2.MOTION_TRANSLATION, _CRITERIA, None, 5
            )
            return np.asarray(warp, dtype=np.float32)
        except cv2.error:
            continue
    return None


def fuse_baseline(frames: Sequence[F32], *, scale: int) -> tuple[F32, dict[str, Any]]:
    """Bicubic up-sampling, ECC translation registration, median.

    Parameters
    ----------
    frames
        2-D frames of one size; ``frames[0]`` is the reference.
    scale
        Integer up-sampling factor.

    Returns
    -------
    image, info
        The fused HR image (float32) and per-frame shifts (LR px, the convention of
        :mod:`elphel_host.mfsr.registration`) with the excluded frames.
    """
    if not frames:
        raise ValueError("frames is empty; allowed: at least one frame")
    scale = check_scale(scale, maximum=None)
    h, w = frames[0].shape
    size = (w * scale, h * scale)
    ref = _upsampled(frames[0], size)
    stack = np.empty((len(frames), size[1], size[0]), dtype=np.float32)
    stack[0] = ref
    used = [0]
    shifts: list[list[float] | None] = [[0.0, 0.0]]
    excluded: list[int] = []
    for i in range(1, len(frames)):
        if frames[i].shape != (h, w):
            raise ValueError(f"frames[{i}].shape={frames[i].shape}; allowed: {(h, w)}")
        up = _upsampled(frames[i], size)
        warp = _ecc_warp(ref, up)
        if warp is None:
            excluded.append(i)
            shifts.append(None)
            continue
        flags = cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP
        stack[len(used)] = cv2.warpAffine(
            up, warp, size, flags=flags, borderMode=cv2.BORDER_REFLECT_101
        )
        used.append(i)
        shifts.append([-float(warp[1, 2]) / scale, -float(warp[0, 2]) / scale])
    fused = np.median(stack[: len(used)], axis=0).astype(np.float32)
    return fused, {"shifts": shifts, "excluded": excluded}
