"""The operator dashboard: static HTML, CSS and JavaScript modules served by the server itself.

No build step: ``static/`` holds the files the browser runs (ES modules, Canvas 2D). ``/`` is the page,
``/static/...`` its files; the page talks to ``/api/v1`` with the session cookie it gets at login. The
files carry no secrets, so they are public; every API route behind them is not.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, FastAPI
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

__all__ = ["STATIC_DIR", "mount", "router"]

STATIC_DIR = Path(__file__).with_name("static")

#: The page may load only its own files and talk only to its own server.
CSP = (
    "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data: blob:; "
    "connect-src 'self'; object-src 'none'; base-uri 'none'; frame-ancestors 'none'; form-action 'self'"
)
HEADERS = {
    "Content-Security-Policy": CSP,
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-cache",
}

router = APIRouter(tags=["dashboard"])


@router.get("/", response_class=FileResponse)
def index() -> FileResponse:
    """The dashboard page (a single page; views are hash routes such as ``#/robots/1``)."""
    return FileResponse(STATIC_DIR / "index.html", headers=HEADERS, media_type="text/html")


class _Static(StaticFiles):
    """Static files with the dashboard's headers; revalidated on every load (``no-cache`` + ETag) so a
    server upgrade never leaves a browser on stale modules."""

    def file_response(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        response = super().file_response(*args, **kwargs)
        response.headers.update({"X-Content-Type-Options": "nosniff", "Cache-Control": "no-cache"})
        return response


def mount(app: FastAPI) -> None:
    """Serve ``/static`` (the page's own files) on ``app``."""
    app.mount("/static", _Static(directory=STATIC_DIR, check_dir=False), name="static")
