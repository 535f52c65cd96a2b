"""Translation registration of burst frames to the first frame, validated.

Convention used throughout ``elphel_host.mfsr``: the shift ``(dy, dx)`` of frame k (LR px)
means that frame k's pixel i sees what the reference frame sees at coordinate ``i + shift``,
i.e. ``frame_k(p) ~ reference(p + shift)``.

Each frame is registered by ``cv2.findTransformECC`` (translation) on a central window of
the frame, started from every available initial guess (phase correlation, the stage/optics
prior); the converged result with the highest correlation wins. A frame is rejected, and
reported, when ECC fails from every start, when its correlation is below a threshold, or
when it lands far from every initial guess that was given.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from elphel_host.mfsr.frames import check_frames
from elphel_host.parallel import parallel_map

F32 = NDArray[np.float32]

_ECC_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-7)


@dataclass(frozen=True)
class FrameRegistration:
    """Registration outcome of one frame.

    Attributes
    ----------
    index
        Frame index in the burst.
    shift
        (dy, dx) in LR px (see module notes), or None when rejected.
    correlation
        ECC correlation coefficient (1 = identical up to gain/offset).
    initial
        Which initial guess gave the accepted result (``reference``, ``phase``, ``prior``).
    ok
        Whether the frame is used for fusion.
    reason
        Why it was rejected (empty when ok).
    """

    index: int
    shift: tuple[float, float] | None
    correlation: float
    initial: str
    ok: bool
    reason: str = ""

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["shift"] = None if self.shift is None else [round(v, 5) for v in self.shift]
        d["correlation"] = round(float(self.correlation), 6)
        return d


def _window(shape: tuple[int, int], max_size: int) -> tuple[slice, slice]:
    h, w = shape
    wh, ww = min(h, max_size), min(w, max_size)
    y0, x0 = (h - wh) // 2, (w - ww) // 2
    return slice(y0, y0 + wh), slice(x0, x0 + ww)


def phase_correlation_shift(reference: F32, frame: F32) -> tuple[float, float]:
    """Shift (dy, dx) of ``frame`` against ``reference`` by windowed phase correlation."""
    win = cv2.createHanningWindow((reference.shape[1], reference.shape[0]), cv2.CV_32F)
    # phaseCorrelate may apply the window to its inputs in place: give it copies
    (sx, sy), _ = cv2.phaseCorrelate(reference.copy(), frame.copy(), win)
    # cv2 reports where the content moved to; the frame sees reference(p + shift)
    return (-float(sy), -float(sx))


def ecc_shift(
    reference: F32, frame: F32, initial: tuple[float, float], *, gauss_size: int = 1
) -> tuple[tuple[float, float], float] | None:
    """ECC translation from ``initial``; returns ((dy, dx), correlation) or None if it fails."""
    # ECC fits reference(x) ~ frame(x + t); frame(p) ~ reference(p + shift) means t = -shift
    warp = np.array([[1.0, 0.0, -initial[1]], [0.0, 1.0, -initial[0]]], dtype=np.float32)
    try:
        cc, warp = cv2.findTransformECC(  # type: ignore[call-overload]
            reference, frame, warp, cv2.MOTION_TRANSLATION, _ECC_CRITERIA, None, gauss_size
        )
    except cv2.error:
        return None
    return (-float(warp[1, 2]), -float(warp[0, 2])), float(cc)


Start = tuple[str, tuple[float, float], float]  # (initial guess's name, shift, correlation)


def _best_start(
    ref: F32, img: F32, starts: dict[str, tuple[float, float]], gauss_size: int
) -> Start | None:
    """ECC from each distinct initial guess; the result of highest correlation."""
    best: Start | None = None
    tried: list[tuple[float, float]] = []
    for name, init in starts.items():
        if any(np.hypot(init[0] - t[0], init[1] - t[1]) < 0.25 for t in tried):
            continue
        tried.append(init)
        res = ecc_shift(ref, img, init, gauss_size=gauss_size)
        if res is not None and (best is None or res[1] > best[2]):
            best = (name, res[0], res[1])
    return best


def _verdict(
    i: int,
    best: Start | None,
    starts: dict[str, tuple[float, float]],
    min_correlation: float,
    max_disagreement_px: float,
) -> FrameRegistration:
    """Frame ``i``'s registration: ECC's result, or why it is rejected."""
    if best is None:
        return FrameRegistration(
            i, None, 0.0, "", False, "ECC did not converge from any initial guess"
        )
    name, shift, cc = best
    if cc < min_correlation:
        return FrameRegistration(
            i, None, cc, name, False, f"correlation {cc:.3f} < {min_correlation}"
        )
    dist = min(float(np.hypot(shift[0] - s[0], shift[1] - s[1])) for s in starts.values())
    if dist > max_disagreement_px:
        reason = f"ECC result {dist:.2f} px from every initial guess (> {max_disagreement_px})"
        return FrameRegistration(i, None, cc, name, False, reason)
    return FrameRegistration(i, shift, cc, name, True)


def register_frames(
    frames: Sequence[F32],
    *,
    prior: Sequence[tuple[float, float]] | None = None,
    window: int = 256,
    min_correlation: float = 0.5,
    max_disagreement_px: float = 1.0,
    gauss_size: int = 5,
) -> list[FrameRegistration]:
    """Register every frame to ``frames[0]``.

    Parameters
    ----------
    frames
        2-D float32 frames of one size (mono, or a luminance image of a Bayer mosaic).
    prior
        Optional predicted shifts (dy, dx) per frame, from the stage and optics.
    window
        Side of the central window used for registration (px); bigger is slower.
    min_correlation
        Frames whose ECC correlation is below this are rejected.
    max_disagreement_px
        A frame whose result is farther than this from every initial guess is rejected
        (ECC slid to a wrong local optimum).
    gauss_size
        ECC pre-blur kernel size (odd; 1 = none).

    Returns
    -------
    list of FrameRegistration
        One per frame; the first is the reference (shift (0, 0)).
    """
    shape = check_frames(frames)
    if prior is not None and len(prior) != len(frames):
        raise ValueError(f"len(prior)={len(prior)}; allowed: {len(frames)} (one per frame)")
    sy, sx = _window(shape, window)
    qy, qx = _window(shape, min(window, 256))
    ref = np.ascontiguousarray(frames[0][sy, sx], dtype=np.float32)
    ref_small = np.ascontiguousarray(frames[0][qy, qx], dtype=np.float32)
    p0 = prior[0] if prior is not None else (0.0, 0.0)

    def register_one(i: int) -> FrameRegistration:
        img = np.ascontiguousarray(frames[i][sy, sx], dtype=np.float32)
        img_small = np.ascontiguousarray(frames[i][qy, qx], dtype=np.float32)
        starts: dict[str, tuple[float, float]] = {
            "phase": phase_correlation_shift(ref_small, img_small),
            "zero": (0.0, 0.0),
        }
        if prior is not None:
            starts["prior"] = (prior[i][0] - p0[0], prior[i][1] - p0[1])
        # pick the start on a small window, then refine on the full one
        best = _best_start(ref_small, img_small, starts, gauss_size)
        if best is not None and (sy, sx) != (qy, qx):
            fine = ecc_shift(ref, img, best[1], gauss_size=gauss_size)
            best = None if fine is None else (best[0], fine[0], fine[1])
        return _verdict(i, best, starts, min_correlation, max_disagreement_px)

    rest = parallel_map(register_one, range(1, len(frames)))  # frames are independent
    return [FrameRegistration(0, (0.0, 0.0), 1.0, "reference", True), *rest]
