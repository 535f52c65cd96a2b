"""Micro-Manager devices for pymmcore-plus's pure-Python core (``UniMMCore``).

``pip install elphel-host[mm]`` brings pymmcore-plus in; the base install does not.
`load_elphel_devices` loads the caliper stage as the focus device and one elphel-camd
sensor port as the camera::

    from pymmcore_plus.experimental.unicore import UniMMCore
    from elphel_host.mm import load_elphel_devices

    core = UniMMCore()
    load_elphel_devices(core, camera_url=URL, token=TOKEN, stage_url=STAGE_URL)
    core.setPosition(42_000.0)  # µm, closed loop on the caliper
    core.snapImage()

See docs/micromanager.md.
"""

from __future__ import annotations

try:
    import pymmcore_plus.experimental.unicore  # noqa: F401
except ImportError as e:  # pragma: no cover - depends on the install
    raise ImportError("elphel_host.mm needs pymmcore-plus: pip install 'elphel-host[mm]'") from e

from elphel_host.mm.camera import ElphelCameraDevice
from elphel_host.mm.loader import CAMERA_LABEL, STAGE_LABEL, load_elphel_devices
from elphel_host.mm.stage import ElphelStageDevice

__all__ = [
    "CAMERA_LABEL",
    "STAGE_LABEL",
    "ElphelCameraDevice",
    "ElphelStageDevice",
    "load_elphel_devices",
]
