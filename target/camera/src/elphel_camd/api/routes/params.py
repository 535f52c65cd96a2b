"""Routes of a port's frame parameters: ``GET`` and ``PATCH /ports/{port}/params``.

A PATCH is validated against `ParamsPatch`, its target frame parsed here, and handed to
`CameraService.set_params`, which schedules it on the port's sequencer. The answer is read
under the same port lock as the write, so it names the frame at which this request's
values are in effect and the parameters of that frame with no other write in between;
concurrent writers are ordered, and the last write of a parameter wins.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query
from fastapi.responses import JSONResponse

from elphel_camd.api.deps import READS, WRITES, FrameQuery, PortPath, Service
from elphel_camd.api.errors import error_responses
from elphel_camd.api.locked import run_locked
from elphel_camd.api.models import Params, ParamsPatch, PatchResult
from elphel_camd.errors import FrameNotAvailableError, ParameterRangeError
from elphel_camd.sequencer import MAX_AHEAD
from elphel_camd.service import CameraService

router = APIRouter()


def parse_frame(frame: str | None, ahead: int | None) -> tuple[int | None, int | None]:
    """``frame=N`` (absolute) or ``frame=+k`` / ``ahead=k`` (relative) from a query.

    Both given are handed on as both (the sequencer refuses the pair).
    """
    if frame is None:
        return None, ahead
    text = frame.strip()
    try:
        value = int(text)
    except ValueError:
        raise ParameterRangeError("frame", frame, "N (absolute) or +k (relative)") from None
    if text.startswith("+") and ahead is None:
        return None, value
    return value, ahead


@router.get(
    "/ports/{port}/params",
    response_model=Params,
    dependencies=READS,
    responses=error_responses(401, 404, 422, 503),
)
async def get_params(service: Service, port: PortPath, frame: FrameQuery = None) -> JSONResponse:
    """Parameters in effect now, or for a recent frame or one up to 14 frames ahead."""
    return JSONResponse(await read_params(service, port, frame))


@router.patch(
    "/ports/{port}/params",
    response_model=PatchResult,
    dependencies=WRITES,
    responses=error_responses(401, 404, 409, 413, 422, 503),
)
async def patch_params(
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
    return JSONResponse(await write_params(service, port, values, absolute, relative))


async def read_params(service: CameraService, port: int, frame: int | None) -> dict[str, int]:
    """What ``GET params`` answers (also called by `elphel_camd.api.fast_path`)."""
    seq = service.sequencer(port)

    def read() -> dict[str, int]:
        if frame is not None and frame > seq.this_frame + MAX_AHEAD:
            raise FrameNotAvailableError(
                f"port {port}: frame {frame} is beyond the schedule (current frame "
                f"{seq.this_frame}; parameters are known up to {MAX_AHEAD} frames ahead)"
            )
        return service.params(port, frame=frame)

    return await run_locked([seq.lock], read)


async def write_params(
    service: CameraService,
    port: int,
    values: dict[str, int],
    absolute: int | None,
    relative: int | None,
) -> dict[str, object]:
    """What ``PATCH params`` does and answers (also called by `elphel_camd.api.fast_path`)."""
    locks = service.param_locks(port, values)  # 404 first; held until the answer is read

    def write() -> dict[str, object]:
        target = service.set_params(port, values, frame=absolute, ahead=relative)
        params = service.params(port, frame=target) if service.scheduled else service.params(port)
        return {"frame": target, "params": params}

    # Without frame syncs the change is written to the sensor at once, and a save synced
    # to the disk each time waits for it: both in a worker thread.
    on_loop = service.scheduled and not service.saves_wait_for_disk
    return await run_locked(locks, write, on_loop=on_loop)
