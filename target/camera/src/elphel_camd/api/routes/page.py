"""The browser page: ``GET /`` (index.html) and its static files under ``/web/``.

The files ship inside the package (``elphel_camd/web``); the page talks only to this
daemon (its Content-Security-Policy, `elphel_camd.api.middleware.HTML_CSP` on every HTML
answer, allows nothing else), so it works on an isolated lab network.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

WEB_DIR = Path(str(files("elphel_camd") / "web"))

router = APIRouter()


@router.get(
    "/",
    response_class=HTMLResponse,
    responses={200: {"content": {"text/html": {}}, "description": "the control page"}},
)
def index() -> HTMLResponse:
    """The browser control page: live view, parameters, capture, events."""
    return HTMLResponse(
        (WEB_DIR / "index.html").read_text(encoding="utf-8"),
        headers={"Cache-Control": "no-cache"},
    )


def static_files() -> StaticFiles:
    """The page's scripts and styles, mounted at ``/web``."""
    return StaticFiles(directory=WEB_DIR)
