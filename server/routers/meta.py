"""Unauthenticated routes: health check and the control-message XSD."""

from __future__ import annotations

import time

from fastapi import APIRouter, Response
from sqlalchemy import text

from server.deps import StateDep
from server.errors import UnavailableError

__all__ = ["api_router", "router"]

router = APIRouter(tags=["meta"])
api_router = APIRouter(tags=["meta"])


@router.get("/healthz")
def healthz(state: StateDep) -> dict[str, str]:
    """``{"status": "ok"}`` when the database answers and its last write found space; 503 otherwise, with
    the reason (a full database fails the check until a write succeeds again)."""
    full = state.db.storage.problem()
    if full is not None:
        reason, since = full
        when = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(since))
        raise UnavailableError(f"the database has had no space left since {when}: {reason}")
    try:
        with state.db.read() as s:
            s.execute(text("SELECT 1"))
    except Exception as exc:  # any database failure means unhealthy, reported not raised
        raise UnavailableError(f"database unavailable: {type(exc).__name__}") from None
    from importlib.metadata import version

    return {"status": "ok", "version": version("linemap")}


@api_router.get(
    "/schema/control.xsd", response_class=Response, responses={200: {"content": {"application/xml": {}}}}
)
def control_xsd() -> Response:
    """The XML Schema of the control message (docs/design.md §6)."""
    from shared.control import xsd_text

    return Response(xsd_text(), media_type="application/xml")
