"""Field ("lazy eye") refinement on the fly, over a sequence of quads.

`elphel tp QUAD_DIR... --out-dir DIR --refine-extrinsics` processes each quad with the
calibration as refined so far, then lets that quad refine it for the next ones. A quad's
DSI gives its tiles' pair mismatches, and :mod:`.field`'s estimator turns them into the
drift still left: the corrections (tilt, azimuth, roll, zoom) of cameras 1-3 that explain
them, each tile's disparity eliminated, the farthest tiles fixing the common disparity
offset, every equation weighted by its peak's strength squared.

The running estimate is the information-weighted mean of what every quad measured: quad
``k``, processed with the drift estimate ``D_k``, says the drift is ``D_k + x_k`` with the
information ``N_k`` (its normal matrix, which carries the strength weights and its number
of tiles). The estimate after it is ``(sum M_k N_k)^-1 sum M_k N_k (D_k + x_k)``, where
each older quad counts ``memory`` times less per quad (``M_k = memory ** age``), so a rig
that keeps drifting is followed and a single poor quad is outweighed by the quads around
it. A quad that finds a large drift (``settle_px`` or more) is taken alone: the earlier
quads were measured too far from where the rig is for their linearised equations to
hold there. A quad with too little texture leaves the estimate as it is.

Each quad's peaks are searched within ``first_search_px`` while the drift it finds is
large (at least half that), within 2 px once it is under 1 px, and in between within
twice the drift found.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from elphel_host.calibrate.field import (
    CORRECTIONS,
    Camera,
    apply_corrections,
    camera_mismatch_px,
    check_texture,
    dsi_equations,
    normal_equations,
    placed_quad,
    robust_solve,
    total_corrections,
)
from elphel_host.errors import InputFormatError
from elphel_host.tp.calibrated import CalibratedGeometry
from elphel_host.tp.config import DEFAULT_CONFIG, TpConfig
from elphel_host.tp.images import QuadImages

F64 = NDArray[np.float64]

_UNKNOWNS = 3 * len(CORRECTIONS)  # the corrections of cameras 1-3


@dataclass(frozen=True)
class QuadUpdate:
    """What one quad of the sequence measured and how it moved the estimate.

    Attributes
    ----------
    updated
        False when the quad had too little texture to measure (the estimate is unchanged).
    mismatch_before_px
        ``(4,)``: per camera, the drift the quad found with the calibration it was
        processed with (RMS over its tiles of the camera's offset from the four cameras'
        mean, px); NaN when not updated.
    mismatch_after_px
        ``(4,)``: the same drift left by the updated estimate, as the quad's own
        equations see it; NaN when not updated.
    tiles, infinity_tiles
        Tiles used, and of them the tiles taken as at infinity.
    search_px
        How far the quad's peaks were searched.
    """

    updated: bool
    mismatch_before_px: F64
    mismatch_after_px: F64
    tiles: int
    infinity_tiles: int
    search_px: int


class RunningField:
    """The drift of cameras 1-3, estimated quad by quad (module docstring).

    Parameters
    ----------
    cameras
        The calibration's cameras (lens, R, t_mm), camera 0 first: the starting point.
    memory
        How much a quad's measurement counts one quad later, 0..1 (0: only the latest).
    settle_px
        A quad that finds a drift this large or larger (px, worst camera) is not averaged
        with the earlier ones: the estimate takes what it says.
    infinity_band_px
        Tiles within this of a quad's farthest disparities are taken as at infinity.
    first_search_px
        How far (px) the peaks are searched while the drift is large (its reach).
    config
        The tile processor's options.
    """

    def __init__(
        self,
        cameras: Sequence[Camera],
        *,
        memory: float = 0.5,
        settle_px: float = 0.25,
        infinity_band_px: float = 0.15,
        first_search_px: int = 6,
        config: TpConfig = DEFAULT_CONFIG,
    ) -> None:
        if not 0.0 <= memory < 1.0 or settle_px <= 0 or infinity_band_px <= 0:
            raise ValueError(
                f"memory={memory}, settle_px={settle_px}, infinity_band_px={infinity_band_px}; "
                "allowed: 0 <= memory < 1, > 0, > 0"
            )
        if not 2 <= first_search_px <= 7:
            raise ValueError(f"first_search_px={first_search_px}; allowed: 2..7")
        self.initial = tuple(cameras)
        self.memory = memory
        self.settle_px = settle_px
        self.infinity_band_px = infinity_band_px
        self.first_search_px = first_search_px
        self.config = config
        self.drift = np.zeros(_UNKNOWNS)
        self.information = np.zeros((_UNKNOWNS, _UNKNOWNS))
        self.evidence = np.zeros(_UNKNOWNS)
        self.search_px = first_search_px
        self.cameras = self.initial
        self.geometry = CalibratedGeometry.from_cameras(self.initial)

    @property
    def corrections(self) -> F64:
        """``(4, 4)``: per camera the (tilt, azimuth, roll, zoom) applied so far."""
        return total_corrections(self.initial, self.cameras)

    def place(self, quad: QuadImages) -> QuadImages:
        """``quad`` with the calibration as refined so far.

        Raises
        ------
        InputFormatError
            The images are of another size than the calibration.
        """
        h, w = quad.images.shape[1:]
        if (w, h) != self.geometry.image_size:
            cw, ch = self.geometry.image_size
            raise InputFormatError(
                f"images of {w}x{h}, the calibration is for {cw}x{ch}; allowed: quads of "
                "the calibrated cameras at that size"
            )
        return placed_quad(quad, self.geometry)

    def update(self, placed: QuadImages, disparity: NDArray[np.floating]) -> QuadUpdate:
        """Refine the estimate with one quad: ``placed`` by :meth:`place`, its DSI's disparity."""
        search = self.search_px
        eq = dsi_equations(placed, disparity, config=self.config, search_px=search)
        try:
            check_texture(eq)
        except InputFormatError:
            nan = np.full(4, np.nan)
            return QuadUpdate(False, nan, nan, 0, 0, search)
        x, weight, infinity = robust_solve(eq, self.infinity_band_px)
        normal, _ = normal_equations(eq, weight, infinity)
        before = camera_mismatch_px(eq, x, weight)
        # earlier quads were measured too far from a large drift to be combined with it
        memory = self.memory if before.max() < self.settle_px else 0.0
        self.information = memory * self.information + normal
        self.evidence = memory * self.evidence + normal @ (self.drift + x)
        solved = np.linalg.lstsq(self.information, self.evidence, rcond=1e-10)[0]
        estimate: F64 = np.asarray(solved, dtype=np.float64)
        after = camera_mismatch_px(eq, x - (estimate - self.drift), weight)
        self._move_to(estimate)
        self.search_px = self._next_search(float(before.max()))
        tiles = int(((weight > 0).sum(1) >= 6).sum())
        return QuadUpdate(True, before, after, tiles, int(infinity.sum()), search)

    def _move_to(self, estimate: F64) -> None:
        self.drift = estimate
        step = np.zeros((4, len(CORRECTIONS)))
        step[1:] = estimate.reshape(3, len(CORRECTIONS))
        self.cameras = apply_corrections(self.initial, step)
        self.geometry = CalibratedGeometry.from_cameras(self.cameras)

    def _next_search(self, found_px: float) -> int:
        if found_px < 1.0:
            return 2
        return int(np.clip(np.ceil(2 * found_px), 2, self.first_search_px))
