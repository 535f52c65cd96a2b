"""The Lepton 3.x telemetry rows: where they sit in a frame and what they say.

With telemetry on, a frame carries two extra rows of 160 words (four packets): as a header
(rows 0-1) or a footer (rows 120-121), as the CCI's SYS telemetry location says. FLIR's
telemetry rows A, B and C are 80 words each: row A is words 0-79 of the first telemetry
row, B words 80-159, C words 0-79 of the second. Source: Lepton Engineering Datasheet
500-0659-00-09, the telemetry tables. The datasheet lists a 32-bit value as two words; they
are read here least significant word first, the order the CCI sends multi-word values in.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

HEIGHT = 120
TELEMETRY_ROWS = 2
HEADER = 0  # SYS telemetry location enum
FOOTER = 1

# Word positions in the two telemetry rows: (row, word). Row A = (0, 0..79), B = (0,
# 80..159), C = (1, 0..79).
REVISION = (0, 0)
UPTIME_MS = (0, 1)  # 2 words
STATUS = (0, 3)  # 2 words
FRAME_COUNTER = (0, 20)  # 2 words, counts unique frames
FRAME_MEAN = (0, 22)
FPA_TEMPERATURE_CENTI_K = (0, 24)
TLINEAR_ENABLED = (1, 48)
TLINEAR_RESOLUTION = (1, 49)  # 0: 0.1 K, 1: 0.01 K

# Status bits (row A words 3-4).
FFC_DESIRED_BIT = 3
FFC_STATE_SHIFT = 4
FFC_STATES = ("never", "imminent", "in_progress", "done")
TLINEAR_RESOLUTIONS_K = {0: 0.1, 1: 0.01}


@dataclass(frozen=True)
class Telemetry:
    """What a frame's telemetry rows say.

    Attributes
    ----------
    revision
        Telemetry format revision.
    uptime_ms
        Camera uptime when the frame was formed.
    frame_counter
        The Lepton's count of unique frames.
    frame_mean
        Mean pixel value of the frame.
    fpa_temperature_centi_k
        Focal-plane-array temperature in 0.01 K.
    ffc_state
        Flat-field correction: ``never``, ``imminent``, ``in_progress`` or ``done``.
    ffc_desired
        Whether the camera asks for a flat-field correction.
    tlinear
        Whether pixels are TLinear scene temperatures.
    tlinear_resolution_k
        Kelvin per count of a TLinear pixel (0.01 or 0.1).
    """

    revision: int
    uptime_ms: int
    frame_counter: int
    frame_mean: int
    fpa_temperature_centi_k: int
    ffc_state: str
    ffc_desired: bool
    tlinear: bool
    tlinear_resolution_k: float

    def to_metadata(self) -> dict[str, Any]:
        """The fields as a capture's metadata carries them (under ``telemetry``)."""
        return asdict(self)


def _word(rows: NDArray[np.uint16], at: tuple[int, int]) -> int:
    return int(rows[at[0], at[1]])


def _long(rows: NDArray[np.uint16], at: tuple[int, int]) -> int:
    return _word(rows, at) | _word(rows, (at[0], at[1] + 1)) << 16


def decode(rows: NDArray[np.uint16]) -> Telemetry:
    """Decode the two telemetry rows of a frame.

    Parameters
    ----------
    rows
        The telemetry rows, shape (2, 160), as the VoSPI words arrived.

    Returns
    -------
    Telemetry
        The decoded fields.
    """
    if rows.shape != (TELEMETRY_ROWS, 160):
        raise ValueError(f"telemetry rows of shape {rows.shape}; allowed: (2, 160)")
    status = _long(rows, STATUS)
    return Telemetry(
        revision=_word(rows, REVISION),
        uptime_ms=_long(rows, UPTIME_MS),
        frame_counter=_long(rows, FRAME_COUNTER),
        frame_mean=_word(rows, FRAME_MEAN),
        fpa_temperature_centi_k=_word(rows, FPA_TEMPERATURE_CENTI_K),
        ffc_state=FFC_STATES[(status >> FFC_STATE_SHIFT) & 0x3],
        ffc_desired=bool(status >> FFC_DESIRED_BIT & 1),
        tlinear=bool(_word(rows, TLINEAR_ENABLED)),
        tlinear_resolution_k=TLINEAR_RESOLUTIONS_K[_word(rows, TLINEAR_RESOLUTION) & 1],
    )


def split(
    rows: NDArray[np.uint16], *, location: int
) -> tuple[NDArray[np.uint16], NDArray[np.uint16] | None]:
    """A frame's image rows and telemetry rows (None without telemetry).

    Parameters
    ----------
    rows
        The frame as assembled, shape (120, 160), or (122, 160) with telemetry.
    location
        Where the telemetry rows are: `HEADER` (0) or `FOOTER` (1).
    """
    if rows.shape[0] == HEIGHT:
        return rows, None
    if rows.shape[0] != HEIGHT + TELEMETRY_ROWS:
        raise ValueError(f"a Lepton frame of {rows.shape[0]} rows; allowed: 120, 122")
    if location == HEADER:
        return rows[TELEMETRY_ROWS:], rows[:TELEMETRY_ROWS]
    if location == FOOTER:
        return rows[:HEIGHT], rows[HEIGHT:]
    raise ValueError(f"telemetry location {location}; allowed: 0 (header), 1 (footer)")
