"""Elphel's MakerNote (Exif tag 0x927C) and what it implies: gamma tables and Bayer order.

An NC393 writes 16 big-endian 32-bit words (older firmware 14, 12 or 8). Channel order
i = 0..3 is red, green of red rows, green of blue rows, blue (the parameters GAINR,
GAING, GAINGB, GAINB). `MakerNote.from_words` decodes them; `linear_lut` inverts the
camera's 257-entry gamma table of one channel into the linear value of each 8-bit code;
`MakerNote.site_channels` and `MakerNote.bayer` say which channel and colour each site
of the read-out 2x2 cell holds once FLIPH, FLIPV and BAYER_MODE are applied.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from elphel_host.errors import Jp4FormatError

JP4 = 5
JP46 = 2
MONO = 0
# Words 0..10 hold the gains, the gamma words, the window and the modes: without them a
# frame cannot be decoded. Older firmware wrote 14, 12 or 8 words.
MIN_WORDS = 11
FULL_SCALE = 65535

# Channel of each site of the cell with no flips and BAYER_MODE 0: G R / B G.
_CELL_CHANNELS = ((1, 0), (3, 2))
_CHANNEL_COLOUR = "RGGB"  # channel i's colour


@dataclass(frozen=True)
class MakerNote:
    """The decoded MakerNote of one frame.

    Attributes
    ----------
    gains
        GAINR, GAING, GAINGB, GAINB, 16.16 fixed point (0x10000 = 1.0).
    gamma, black, gamma_scale
        Per channel (R, Gr, Gb, B): gamma (0.57 ...), black level as a fraction of full
        scale (multiples of 1/256) and the table's scale (0x400 = 1.0).
    woi
        WOI_LEFT, WOI_TOP, WOI_WIDTH, WOI_HEIGHT.
    fliph, flipv, bayer_mode, color_mode
        The readout's mirrors, the BAYER shift and the compressor's COLOR_MODE.
    decimation, binning
        (horizontal, vertical) as stored (0 and 1 both mean none).
    composite
        The frame is a composite of several sub-frames (word 10, bits 31:30).
    quality
        JPEG quality (word 13), None when the note is shorter.
    """

    gains: tuple[int, int, int, int]
    gamma: tuple[float, float, float, float]
    black: tuple[float, float, float, float]
    gamma_scale: tuple[int, int, int, int]
    woi: tuple[int, int, int, int]
    fliph: int
    flipv: int
    bayer_mode: int
    color_mode: int
    decimation: tuple[int, int] = (1, 1)
    binning: tuple[int, int] = (1, 1)
    composite: bool = False
    quality: int | None = None

    @classmethod
    def from_words(cls, words: Sequence[int]) -> MakerNote:
        """Decode the note's words.

        Raises
        ------
        Jp4FormatError
            Fewer than 11 words (a short MakerNote).
        """
        if len(words) < MIN_WORDS:
            raise Jp4FormatError(
                f"short MakerNote: {len(words)} words; need at least {MIN_WORDS} "
                "(gains, gamma, window and colour mode)"
            )
        w = [int(v) & 0xFFFFFFFF for v in words]
        gamma_words = w[4:8]
        mode = w[10]
        return cls(
            gains=(w[0], w[1], w[2], w[3]),
            gamma=_four([((g >> 16) & 0xFF) / 100 for g in gamma_words]),
            black=_four([(g >> 24) / 256 for g in gamma_words]),
            gamma_scale=(
                gamma_words[0] & 0xFFFF,
                gamma_words[1] & 0xFFFF,
                gamma_words[2] & 0xFFFF,
                gamma_words[3] & 0xFFFF,
            ),
            woi=(w[8] & 0xFFFF, w[9] & 0xFFFF, w[8] >> 16, w[9] >> 16),
            fliph=mode & 1,
            flipv=(mode >> 1) & 1,
            bayer_mode=(mode >> 2) & 3,
            color_mode=(mode >> 4) & 0xF,
            decimation=((mode >> 8) & 0xF, (mode >> 12) & 0xF),
            binning=((mode >> 16) & 0xF, (mode >> 20) & 0xF),
            composite=bool(mode >> 30),
            quality=w[13] & 0x7F if len(w) > 13 else None,
        )

    def site_channels(self) -> NDArray[np.intp]:
        """Channel (0 R, 1 Gr, 2 Gb, 3 B) of each site of the read-out 2x2 cell."""
        h = self.fliph ^ (self.bayer_mode & 1)
        v = self.flipv ^ (self.bayer_mode >> 1)
        cell = np.array(_CELL_CHANNELS, dtype=np.intp)
        if v:
            cell = cell[::-1, :]
        if h:
            cell = cell[:, ::-1]
        return cell

    @property
    def bayer(self) -> str:
        """Colour order of the read-out cell (``"GRBG"`` unflipped)."""
        return "".join(_CHANNEL_COLOUR[c] for c in self.site_channels().ravel())


def _four(values: Sequence[float]) -> tuple[float, float, float, float]:
    return (values[0], values[1], values[2], values[3])


def gamma_table(gamma: float, black: float, scale: int) -> NDArray[np.float64]:
    """The camera's 257-entry gamma table of one channel (values 0..0xFFFF).

    Entry i is ``round(65535 x**gamma) * scale / 0x400`` clipped at 0xFFFF, where
    ``x = (i - 256 black) / (256 - 256 black)`` is clipped below at 0 and the gamma is
    clamped to [0.13, 10].
    """
    g = float(np.clip(gamma, 0.13, 10.0))
    x = (np.arange(257, dtype=np.float64) - 256.0 * black) / (256.0 * (1.0 - black))
    table = np.round(65535.0 * np.maximum(x, 0.0) ** g) * (scale / 0x400)
    out: NDArray[np.float64] = np.minimum(np.floor(table), 0xFFFF)
    return out


def code_positions(gamma: float, black: float, scale: int) -> NDArray[np.float64]:
    """Table position (0..256) at which the interpolated table reaches each code's centre.

    Code c covers the table values 256c .. 256c + 255; its centre 256c + 128 is reached
    at position p (fractional, linear interpolation between entries); p / 256 is the
    linear value as a fraction of full scale. Codes beyond the table's top map to 256.
    """
    table = gamma_table(gamma, black, scale)
    target = 256.0 * np.arange(256) + 128.0
    upper = np.searchsorted(table, target, side="left")  # first entry >= the target
    hi = np.clip(upper, 1, 256)
    lo = hi - 1
    rise = table[hi] - table[lo]
    frac = np.where(rise > 0, (target - table[lo]) / np.where(rise > 0, rise, 1.0), 0.0)
    p = np.where(upper > 256, 256.0, lo + np.clip(frac, 0.0, 1.0))
    out: NDArray[np.float64] = np.where(upper == 0, 0.0, p)
    return out


@functools.lru_cache(maxsize=64)
def linear_lut(gamma: float, black: float, scale: int) -> NDArray[np.uint16]:
    """Linear 16-bit value of each 8-bit code of one channel (read-only, cached).

    The value is (p - 256 black) / 256 of full scale, times 65535, rounded and clipped
    at 0: the black level is subtracted, the gains are not divided out.
    """
    p = code_positions(gamma, black, scale)
    linear = np.clip(np.round((p - 256.0 * black) / 256.0 * FULL_SCALE), 0, FULL_SCALE)
    lut = linear.astype(np.uint16)
    lut.setflags(write=False)
    return lut
