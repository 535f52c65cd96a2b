"""Which sensor port is which camera of the quad, and where each camera sits.

A capture needs it and the daemon does not know it: it comes from a ``--geometry`` file
(a quad.json works as one, and so does the simulator's ``GET {sim_url}/quad``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from elphel_host import strict_json
from elphel_host.errors import InputFormatError
from elphel_host.tp.geometry import IDEAL_POSITIONS, QuadGeometry
from elphel_host.tp.io import camera_list, parse_position


@dataclass(frozen=True)
class QuadLayout:
    """Which sensor port is camera i of the quad, and where camera i sits.

    Parameters
    ----------
    ports
        Sensor port of cameras 0..3.
    positions
        Camera centres in units of the square's side, +x right, +y down.
    optics
        Optional optics record copied into quad.json (``focal_length_mm``, ...).
    """

    ports: tuple[int, ...] = (0, 1, 2, 3)
    positions: tuple[tuple[float, float], ...] = IDEAL_POSITIONS
    optics: Mapping[str, Any] | None = None

    def __post_init__(self) -> None:
        if len(self.ports) != 4 or len(set(self.ports)) != 4:
            raise InputFormatError(f"ports={list(self.ports)}; allowed: four different ports")
        QuadGeometry(positions=self.positions)  # checks the positions


def read_layout(path: str | Path) -> QuadLayout:
    """A ``--geometry`` file: ``{"cameras": [{"position": [x, y], "port": P}, ...]}``.

    Four cameras in quad order; ``port`` defaults to the camera's index; an ``optics``
    object is copied into quad.json. A quad.json works as a geometry file, and so does
    the simulator's ``GET {sim_url}/quad``.

    Raises
    ------
    InputFormatError
        When the file is not JSON or does not have this form.
    """
    file = Path(path)
    doc = strict_json.load_file(file)
    ports: list[int] = []
    positions: list[tuple[float, float]] = []
    for i, cam in enumerate(camera_list(doc, str(file))):
        pos = cam.get("position") if isinstance(cam, dict) else None
        positions.append(parse_position(pos, f"{file}: cameras[{i}]"))
        port = cam.get("port", i)
        if not isinstance(port, int) or isinstance(port, bool) or port < 0:
            raise InputFormatError(f"{file}: cameras[{i}].port={port!r}; allowed: a port number")
        ports.append(port)
    optics = doc.get("optics")
    if optics is not None and not isinstance(optics, dict):
        raise InputFormatError(f"{file}: optics={optics!r}; allowed: an object")
    return QuadLayout(ports=tuple(ports), positions=tuple(positions), optics=optics)
