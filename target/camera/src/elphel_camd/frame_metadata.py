"""What a captured frame says about itself: the JSON metadata of its TIFF page.

`frame_metadata` builds the object a capture's ImageDescription carries (frame number,
time, port, sensor, Bayer order, the parameters in effect, photo-finish strips);
`bayer_after_flips` is the Bayer order of the first pixel once the readout is mirrored.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from elphel_camd.boards.base import Frame


def bayer_after_flips(bayer: str | None, fliph: int, flipv: int) -> str | None:
    """Bayer pattern of the first pixel once the readout is mirrored (even window sizes)."""
    if bayer is None:
        return None
    cell = [bayer[0:2], bayer[2:4]]
    if flipv:
        cell = cell[::-1]
    if fliph:
        cell = [row[::-1] for row in cell]
    return cell[0] + cell[1]


def frame_metadata(
    got: Frame, *, port: int, sensor: str, bayer: str | None, params: Mapping[str, int]
) -> dict[str, Any]:
    """The metadata of one captured frame.

    Parameters
    ----------
    got
        The frame as the board delivered it.
    port
        Its sensor port.
    sensor
        The sensor model on that port.
    bayer
        The sensor's Bayer order without flips (None for a mono sensor).
    params
        The parameters in effect for that frame.

    Returns
    -------
    dict
        ``frame``, ``timestamp_ns``, ``port``, ``sensor``, ``bayer`` (after the flips), every
        parameter, what the board adds to the frame (a Lepton's telemetry and pixel unit),
        and for a photo-finish composite ``pf_strips`` and ``pf_strip_period_ns``.
    """
    metadata: dict[str, Any] = {
        "frame": got.frame,
        "timestamp_ns": got.timestamp_ns,
        "port": port,
        "sensor": sensor,
        "bayer": bayer_after_flips(bayer, params.get("FLIPH", 0), params.get("FLIPV", 0)),
        **params,
        **got.metadata,
    }
    if params.get("PF_HEIGHT"):
        # Row r of a composite was read in strip r // PF_HEIGHT, which started at
        # timestamp_ns + (r // PF_HEIGHT) * pf_strip_period_ns.
        period = got.strip_period_ns or round(1e12 / max(params["FP1000S"], 1))
        metadata["pf_strips"] = params["WOI_HEIGHT"] // params["PF_HEIGHT"]
        metadata["pf_strip_period_ns"] = period
    return metadata
