"""First start: make sure an operator can log in (creates the ``admin`` token once, shown once)."""

from __future__ import annotations

from sqlalchemy import func, select

from server.database import Database
from server.migrate import hold_schema_lock
from server.models import AuditEntry, OperatorToken
from server.routers.auth import create_operator_token

__all__ = ["create_token", "ensure_admin_token"]


def ensure_admin_token(db: Database) -> str | None:
    """A new ``admin`` operator token if the database has no operator token yet, else ``None``."""
    with db.session() as s:
        hold_schema_lock(s.connection())  # processes starting together: only the first makes one
        if s.scalar(select(func.count()).select_from(OperatorToken)):
            return None
        tid, token = create_operator_token(s, "admin")
        s.add(
            AuditEntry(
                actor="server", action="token.create", target=f"operator:{tid}", detail={"name": "admin"}
            )
        )
        return token


def create_token(db: Database, name: str) -> str:
    """A new operator token named ``name`` (``linemap server token create``)."""
    with db.session() as s:
        tid, token = create_operator_token(s, name)
        s.add(AuditEntry(actor="cli", action="token.create", target=f"operator:{tid}", detail={"name": name}))
        return token
