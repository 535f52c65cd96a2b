"""Routes of a port's frame parameters: ``GET`` and ``PATCH /ports/{port}/params``.

A PATCH is validated against `ParamsPatch`, its target frame parsed here, and handed to
`CameraService.set_params`, which schedules it on the port's sequencer.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query
from fastapi.responses import JSONResponse

from elphel_camd.api.deps import READS, WRITES, FrameQuery, PortPath, Service
from elphel_camd.api.errors import error_responses
from elphel_camd.api.models import Params, ParamsPatch, PatchResult
from elphel_camd.errors import ParameterRangeError, UnsupportedError

router = APIRouter()


def parse_frame(frame: str | None, ahead: int | None) -> tuple[int | None, int | None]:
    """``frame=N`` (absolute) or ``frame=+k`` / ``ahead=k`` (relative) from a query."""
    if frame is not None and ahead is not None:
        raise UnsupportedError("give frame or ahead, not both")
    if frame is None:
        return None, ahead
    text = frame.strip()
    try:
        value = int(text)
    except ValueError:
        raise ParameterRangeError("frame", frame, "N (absolute) or +k (relative)") from None
    if text.startswith("+"):
        return None, value
    return value, None


@router.get(
    "/ports/{port}/params",
    response_model=Params,
    dependencies=READS,
    responses=error_responses(401, 404, 422, 503),
)
def get_params(service: Service, port: PortPath, frame: FrameQuery = None) -> JSONResponse:
    """Parameters in effect now, or for a recent or scheduled frame."""
    return JSONResponse(service.params(port, frame=frame))


@router.patch(
    "/ports/{port}/params",
    response_model=PatchResult,
    dependencies=WRITES,
    responses=error_responses(401, 404, 413, 422, 503),
)
def patch_params(
    service: Service,
    port: PortPath,
    changes: ParamsPatch,  # type: ignore[valid-type]
    frame: Annotated[
        str | None,
        Query(
            pattern=r"^\s*\+?[0-9]{1,10}\s*$",
            description="target frame: N (absolute) or +k (k frames ahead)",
        ),
    ] = None,
    ahead: Annotated[int | None, Query(ge=0, le=0x7FFFFFFF, description="same as frame=+k")] = None,
) -> JSONResponse:
    """Set parameters (all or none), now or at a frame; answers the frame they take effect."""
    absolute, relative = parse_frame(frame, ahead)
    values = changes.model_dump(exclude_unset=True)  # type: ignore[attr-defined]
    target = service.set_params(port, values, frame=absolute, ahead=relative)
    params = service.params(port, frame=target) if service.scheduled else service.params(port)
    return JSONResponse({"frame": target, "params": params})
