"""Routes of the board as a whole: ``GET /info`` and ``GET /health``."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from elphel_camd.api.deps import READS, Service
from elphel_camd.api.errors import error_responses
from elphel_camd.api.models import Health, Info

router = APIRouter()


@router.get("/info", response_model=Info, dependencies=READS, responses=error_responses(401, 503))
def info(service: Service) -> JSONResponse:
    """Board, daemon version, and each port with its detected sensor."""
    return JSONResponse(service.info())


@router.get(
    "/health",
    response_model=Health,
    responses={
        503: {"model": Health, "description": "a port's I2C bus fails or its frames stopped"}
    },
)
def health(service: Service) -> JSONResponse:
    """Each sensor answering on its bus now, and its frame stream where there is one.

    503 (status degraded) if a sensor does not answer or its frames stopped.
    """
    report = service.health()
    return JSONResponse(report, status_code=200 if report["status"] == "ok" else 503)
