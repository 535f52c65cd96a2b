"""The API's routers, one per resource group, in the order the app includes them."""

from fastapi import APIRouter

from elphel_camd.api.routes import events, frames, info, params, registers

ROUTERS: tuple[APIRouter, ...] = (
    info.router,
    params.router,
    frames.router,
    registers.router,
    events.router,
)

__all__ = ["ROUTERS"]
