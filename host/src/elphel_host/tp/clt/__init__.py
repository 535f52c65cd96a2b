"""The complex lapped transform (CLT) of the tile processor, in its three forms.

* :mod:`~elphel_host.tp.clt.transform` — the definition, tile by tile: sine window, MDCT/MDST
  fold, DCT-IV/DST-IV, inverse and overlap-add, phase rotation, the complex form.
  Its names are re-exported here (``clt.clt_tiles``, ``clt.E_COMPLEX``, ...).
* :mod:`~elphel_host.tp.clt.reference` — the reference lattice transform: one colour
  lattice of one camera, for a batch of shifted tiles, written straight from the
  definition. It is what the fast path is tested against, not what production runs.
* :mod:`~elphel_host.tp.clt.batch` — the production path: every colour of one camera's
  tiles by a separable transform in one compiled pass, only on the frequencies the
  correlation keeps.
"""

from __future__ import annotations

from elphel_host.tp.clt.transform import (
    C4,
    E_COMPLEX,
    FOLD_C,
    FOLD_S,
    OMEGA,
    S4,
    T_COS,
    T_SIN,
    TILE,
    N,
    clt_image,
    clt_tiles,
    extract_tiles,
    from_complex,
    iclt_image,
    iclt_tiles,
    overlap_add,
    rotate,
    tile_grid,
    to_complex,
    window,
)

__all__ = [
    "C4",
    "E_COMPLEX",
    "FOLD_C",
    "FOLD_S",
    "OMEGA",
    "S4",
    "TILE",
    "T_COS",
    "T_SIN",
    "N",
    "clt_image",
    "clt_tiles",
    "extract_tiles",
    "from_complex",
    "iclt_image",
    "iclt_tiles",
    "overlap_add",
    "rotate",
    "tile_grid",
    "to_complex",
    "window",
]
