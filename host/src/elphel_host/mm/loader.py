"""`load_elphel_devices`: the rig's camera and stage in a pymmcore-plus ``UniMMCore``."""

from __future__ import annotations

from pathlib import Path

from pymmcore_plus.experimental.unicore import UniMMCore

from elphel_host.camera.client import CameraClient, CameraUnauthorizedError
from elphel_host.errors import CameraAuthError
from elphel_host.mm.camera import ElphelCameraDevice
from elphel_host.mm.stage import ElphelStageDevice

CAMERA_LABEL = "ElphelCamera"
STAGE_LABEL = "ElphelStage"
# A closed-loop move creeps its last steps with a caliper reading at each (seconds);
# Micro-Manager's default 5 s device timeout is too short for one.
DEFAULT_TIMEOUT_MS = 120_000


def load_elphel_devices(
    core: UniMMCore,
    *,
    camera_url: str | None = None,
    token: str | None = None,
    stage_url: str | None = None,
    port: int = 0,
    stage_model: str | Path | None = None,
    home: bool = True,
    timeout_ms: int = DEFAULT_TIMEOUT_MS,
) -> list[str]:
    """Load, initialise and select the rig's camera and stage; return their labels.

    Parameters
    ----------
    core
        A ``pymmcore_plus.experimental.unicore.UniMMCore``.
    camera_url, token, port
        An elphel-camd daemon, its token and the sensor port: loaded as `CAMERA_LABEL`
        and made the core's camera.
    stage_url, stage_model, home
        The stage's pyserial URL, an optional calibration file (``elphel stage
        calibrate --model``) and whether to home an unhomed stage: loaded as
        `STAGE_LABEL` and made the focus device (positions in µm, caliper frame).
    timeout_ms
        The core's device timeout, raised to this if lower (closed-loop moves take
        seconds).

    Raises
    ------
    ValueError
        Neither a camera nor a stage was given.
    CameraAuthError
        The camera refused the token (or needs one): raised here, before anything is
        loaded, rather than at the first image.
    """
    if camera_url is None and stage_url is None:
        raise ValueError("load_elphel_devices: give camera_url, stage_url or both")
    labels = []
    if camera_url is not None:
        check_camera_token(camera_url, token, port)
        camera = ElphelCameraDevice(camera_url, token, port=port)
        core.loadPyDevice(CAMERA_LABEL, camera)
        core.initializeDevice(CAMERA_LABEL)
        core.setCameraDevice(CAMERA_LABEL)
        labels.append(CAMERA_LABEL)
    if stage_url is not None:
        stage = ElphelStageDevice(stage_url, model_path=stage_model, home_on_init=home)
        core.loadPyDevice(STAGE_LABEL, stage)
        core.initializeDevice(STAGE_LABEL)
        core.setFocusDevice(STAGE_LABEL)
        labels.append(STAGE_LABEL)
        # The MDA engine leaves the position out of frames it acquires as one camera
        # sequence (several time points at one position) because reading a stage can be
        # slow; this stage answers from its last caliper-verified position, so keep it.
        engine = core.mda.engine
        if engine is not None:
            engine.include_frame_position_metadata = True
    if core.getTimeoutMs() < timeout_ms:
        core.setTimeoutMs(timeout_ms)
    return labels


def check_camera_token(url: str, token: str | None, port: int) -> None:
    """Read the port's parameters once, so that a refused token fails at load time.

    Raises
    ------
    CameraAuthError
        "wrong token" when one was given and refused, else that the camera needs one.
    """
    try:
        with CameraClient(url, token) as client:
            client.params(port)
    except CameraUnauthorizedError as e:
        if token:
            raise CameraAuthError(
                f"wrong token: the camera at {url} refused it (HTTP {e.status})"
            ) from e
        raise CameraAuthError(
            f"the camera at {url} needs its token (HTTP {e.status}): pass token=..."
        ) from e
