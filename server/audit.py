"""The audit log: every operator action is written in the same transaction as the action itself."""

from __future__ import annotations

from typing import Any

from sqlalchemy.orm import Session

from server.deps import Principal
from server.models import AuditEntry

__all__ = ["record"]


def record(session: Session, who: Principal, action: str, target: str, **detail: Any) -> None:
    """Add one entry (``action`` like ``robot.register``, ``target`` like ``robot:3``); never log secrets."""
    session.add(AuditEntry(actor=who.actor, action=action, target=target, detail=detail))
