"""Colour lattices of a Bayer mosaic and the colour weights of the correlation.

A GRBG sensor has green at (even row, even column), red at (even, odd), blue at
(odd, even) and green at (odd, odd). Each colour is processed on its own sub-lattice of
8x8 samples per 16x16 tile, so red and blue cost one quarter of a full-tile transform and
green two quarters: this is the symmetry of a Bayer lattice under the CLT (R/B need only
the cosine-cosine part, G only cosine-cosine and sine-cosine), applied by never computing
the zeros. Colour indices follow Elphel's tile processor: R = 0, B = 1, G = 2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from elphel_host.errors import InputFormatError

COLOURS_BAYER = ("red", "blue", "green")
COLOURS_MONO = ("mono",)
BAYER_PATTERNS = ("GRBG", "RGGB", "GBRG", "BGGR")


@dataclass(frozen=True)
class Lattice:
    """One sampling lattice of the sensor: every ``step``-th pixel from (row, col).

    Attributes
    ----------
    colour
        Index into the colour tuple (R=0, B=1, G=2 for Bayer; 0 for mono).
    row, col
        Parity of the lattice's rows and columns on the sensor.
    step
        2 for a Bayer colour, 1 for a mono sensor.
    scale
        Multiplier of the samples (green 0.5: it has twice the pixels of red or blue).
    """

    colour: int
    row: int
    col: int
    step: int
    scale: float = 1.0

    @property
    def samples(self) -> int:
        """Samples per tile along one axis."""
        return 16 // self.step


def lattices(bayer: str | None) -> tuple[Lattice, ...]:
    """Lattices of a sensor: one for mono (``None``), four for a Bayer pattern.

    Parameters
    ----------
    bayer
        ``None`` or one of ``GRBG``, ``RGGB``, ``GBRG``, ``BGGR`` (colours of the 2x2 cell
        at even row/col, odd col, odd row, odd row/col).
    """
    if bayer is None:
        return (Lattice(colour=0, row=0, col=0, step=1),)
    if bayer not in BAYER_PATTERNS:
        raise InputFormatError(
            f"bayer pattern {bayer!r}; allowed: null or one of {', '.join(BAYER_PATTERNS)}"
        )
    index = {"R": 0, "B": 1, "G": 2}
    out = []
    for pos, letter in enumerate(bayer):
        out.append(
            Lattice(
                colour=index[letter],
                row=pos // 2,
                col=pos % 2,
                step=2,
                scale=0.5 if letter == "G" else 1.0,
            )
        )
    return tuple(out)


def colour_names(bayer: str | None) -> tuple[str, ...]:
    return COLOURS_MONO if bayer is None else COLOURS_BAYER


def colour_weights(
    bayer: str | None, *, red: float = 0.5, blue: float = 0.2
) -> NDArray[np.float64]:
    """Weights of each colour's correlation in the sum (reference 6.3): R, B, G.

    Parameters
    ----------
    bayer
        Pattern or ``None`` (mono: weight 1).
    red, blue
        Red and blue weights relative to green; the three are normalised to sum to 1.
    """
    if bayer is None:
        return np.ones(1)
    if red < 0 or blue < 0:
        raise ValueError(f"colour weights red={red}, blue={blue}; allowed: >= 0")
    g = 1.0 / (1.0 + red + blue)
    return np.array([red * g, blue * g, g])


def sublattice(image: NDArray[np.floating], lattice: Lattice, *, pad: int) -> NDArray[np.float32]:
    """The samples of one lattice as a float32 image, padded by ``pad`` edge samples.

    Edge padding of the sub-image is the reference's clamping of out-of-image samples to
    the nearest border pixel of the same Bayer parity.
    """
    sub = np.asarray(image, dtype=np.float32)[
        lattice.row :: lattice.step, lattice.col :: lattice.step
    ]
    out: NDArray[np.float32] = np.pad(sub * np.float32(lattice.scale), pad, mode="edge")
    return out
